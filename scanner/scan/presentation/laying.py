"""Laying the object on a support (the table's top, the turntable's disc): what the person is
asked (the next-best face in words and a picture, or a quarter turn towards the robot without a
plan), and the world once it lies so: the simulated person lays it with a person's error
(robots/simulation/laying.py), hardware asks one (`Hardware.request_rehang`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.evaluation.coverage import SeenSurface
from robots.simulation.laying import laid_pose
from scanner.configs.scan import ScanConfig
from scanner.reports.rehang_picture import write_rehang_picture
from scanner.scan.presentation.next_face import FaceChoice, face_words, lay_instruction
from scanner.scan.world import ScanWorld


def lay(config: ScanConfig, world: ScanWorld, index: int, asked: dict, viewer=None) -> ScanWorld:
    """The world once the object lies as `asked` (`down_W`: the side, of the object as it
    lies now, to put underneath; `words`: what the person is told) on the support for pass
    `index`: the simulated person lays it (robots/simulation/laying.py), hardware asks one.
    `toward_W` (optional): the side, as it lies now, to turn towards the robot."""
    if world.sim is not None:
        X_WO = laid_pose(
            config.cell,
            world.sim.object_mesh,
            world.sim.truth.X_WO,
            np.asarray(asked["down_W"], float),
            config.error_model.seed,
            index,
            None if "toward_W" not in asked else np.asarray(asked["toward_W"], float),
        )
        return world.with_object_at(X_WO, viewer)
    if world.hardware is None or world.hardware.request_rehang is None:
        raise ScannerError(
            "this driver cannot ask for the object to be laid on another face "
            "(Hardware.request_rehang is None): scan one pass per run (hangings: 1) and "
            "combine the scans with scanner merge"
        )
    world.hardware.request_rehang(asked["words"])
    return world


def face_request(
    seen: SeenSurface,
    choice: FaceChoice,
    centre_W: np.ndarray,
    index: int,
    scan_root: Path,
    support: str = "table",
) -> dict:
    """The request to lay the object as `choice` says for pass `index`, in words and a picture
    (written beside the captures: a reconstruction writes results/ anew)."""
    name = f"lay_{index + 1}.png"
    heading = (
        f"Pass {index + 1}: lay the object on the side the blue arrow points to (the green "
        f"star touches the {support}), the orange arrow's side towards the robot; red: not "
        "seen yet"
    )
    write_rehang_picture(
        seen,
        choice.down_W,
        choice.touch_W,
        centre_W,
        index,
        scan_root / name,
        heading,
        choice.toward_W,
    )
    return {
        "down_W": [float(x) for x in choice.down_W],
        "toward_W": [float(x) for x in choice.toward_W],
        "touch_W": [float(x) for x in choice.touch_W],
        "face": face_words(choice.down_W),
        "face_probability": choice.probability,
        "expected_gain": choice.gain,
        "expected_overlap": choice.overlap,
        "words": lay_instruction(choice, index, str(scan_root / name), support),
        "picture": name,
    }


def quarter_turn(index: int, support: str = "table") -> dict:
    """The request of a pass without a plan: the side facing the robot now goes underneath, a
    quarter turn (two of them turn it upside down). Not half a turn at once: the cameras see
    one cap of the object (from above and the robot's side), so an object turned upside down
    shows the next pass only a thin band of what the pass before saw, too little to align the
    passes on."""
    towards_robot = np.array([-1.0, 0.0, 0.0])
    return {
        "down_W": [float(x) for x in towards_robot],
        "face": face_words(towards_robot),
        "words": (
            f"pass {index + 1}: roll the object a quarter turn towards the robot and lay it on "
            f"the {support} on {face_words(towards_robot)}, in the middle of the {support}, at "
            "any turn about the vertical; then confirm"
        ),
    }

"""`scanner preview`: render the simulated cell and one stereo pair, to show the set-up works."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from planners.ik import Viewpoint, camera_pose, ik_camera, look_at_rotation, rig_centre_offset
from reconstruction.common.errors import ScannerError
from reconstruction.common.sphere import fibonacci_directions
from robots.models import camera_tool
from robots.models.workcell import WorkcellConfig
from robots.simulation.cell import HOME_Q, create_simulation
from robots.simulation.stereo_camera import render_overview
from robots.simulation.truth import ErrorModel


@dataclass(frozen=True)
class PreviewResult:
    overview_png: Path
    left_png: Path
    right_png: Path
    q: np.ndarray


def first_reachable_view(sim, radius_m: float) -> tuple[Viewpoint, np.ndarray]:
    """A reachable view from the robot's side of the object, slightly from below."""
    c = np.array(sim.workcell.config.object_center_m)
    X_FC = camera_tool.nominal_X_FC(sim.truth.stereo.baseline_m)
    X_MC = rig_centre_offset(sim.truth.stereo.X_CR)
    preferred = np.array([-1.0, 0.0, -0.3]) / np.linalg.norm([-1.0, 0.0, -0.3])
    directions = fibonacci_directions(400)
    arm = sim.robot.arm
    for d in directions[np.argsort(-directions @ preferred)]:
        vp = Viewpoint(tuple(c + radius_m * d), tuple(c), 0.0)
        solutions = ik_camera(arm, camera_pose(vp, X_MC), X_FC, HOME_Q)
        if solutions:
            return vp, min(solutions, key=lambda q: float(np.abs(q - HOME_Q).max()))
    raise ScannerError("no reachable viewpoint for the preview; move the object closer")


def _save_rgb(path: Path, rgb: np.ndarray) -> Path:
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return path


def run_preview(object_spec: str, out_dir: Path, seed: int, radius_m: float = 0.5) -> PreviewResult:
    out_dir.mkdir(parents=True, exist_ok=True)
    sim = create_simulation(WorkcellConfig(), object_spec, ErrorModel(seed=seed))
    viewpoint, q = first_reachable_view(sim, radius_m)
    # The preview teleports the arm: no motion is executed, so no planning is needed.
    sim.robot.teleport(q)
    pair = sim.camera.capture()
    p_WV = np.array([1.9, 1.3, 1.3])
    X_WV = np.eye(4)
    X_WV[:3, :3] = look_at_rotation(p_WV, np.array([0.1, 0.0, 0.45]))
    X_WV[:3, 3] = p_WV
    overview = render_overview(sim.workcell, sim.robot.true_joint_positions(), X_WV)
    return PreviewResult(
        _save_rgb(out_dir / "overview.png", overview),
        _save_rgb(out_dir / "left.png", pair.left),
        _save_rgb(out_dir / "right.png", pair.right),
        q,
    )

"""The next-best face of an object on the table: the stable resting pose whose pass newly sees
most of what the passes so far have not.

The same coverage machinery as the next-best hanging (`scanner.scan.next_hanging`): laying the
object on the face with outward normal n (of the model as it lies now) turns it by R, the
smallest turn that takes n down, then by a yaw about the vertical; for the cameras that is
turning them by R^T about the centre, and a candidate's gain is the share of the closed model's
unseen samples the pass's cameras would see after it. The person is told which side to turn
towards the robot (the best yaw for the face), and turns it so by eye: the gain is averaged over
yaws within that error. The arm sees a lying object from above and from its own side, so the
yaw decides whether an unseen side faces the cameras or away. The pass is then aligned on what
it sees again: a candidate whose pass would see less than `MIN_PASS_OVERLAP` of surface seen
before counts its gain in proportion. Unlike a hanging, only the
faces the model can rest on are candidates: its hull's faces that hold its centre of mass
(reconstruction/hangings/resting_poses.py), computed on the closed model so far; and the face
laid down is hidden from that pass by the support it lies on, whatever the views.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.transforms import rotation_about
from reconstruction.evaluation.coverage import SeenSurface
from reconstruction.evaluation.support import SupportPlane
from reconstruction.hangings.resting_poses import centre_of_mass, resting_poses
from scanner.scan.next_hanging import UP, seen_sight, side_name, unseen_sight

# A face whose edge is this close to the centre of mass tips over at a nudge: a person laying
# the object puts it down a few millimetres off, and the model so far is a few off itself.
MIN_MARGIN_M = 0.005
# The most probable faces considered: a tessellated round side is many thin faces, and the
# gain of neighbouring ones differs by less than the person's yaw averages out.
MAX_FACES = 16
# A face within this of the one underneath now is where the object lies already.
SAME_FACE_RAD = math.radians(20.0)
# Yaws tried for each face, and how far off the asked heading a person turns the object by eye.
YAW_STEPS = 36
PERSON_YAW_ERROR_RAD = math.radians(20.0)
TOWARD_ROBOT = np.array([-1.0, 0.0, 0.0])  # the robot stands at the origin, the object along +x
# The pass is aligned on what it sees again: a face that shows mostly new surface leaves it too
# little (the fandisk laid to show all it had not: 30 % of its points on the first pass's, and
# aligned 1.1 mm / 0.34 deg off). Below this share of the pass's surface seen before, a
# candidate's gain counts in proportion.
MIN_PASS_OVERLAP = 0.5


@dataclass(frozen=True, eq=False)
class FaceChoice:
    """Lay the object on the side facing `down_W` now (unit, cell frame of the pass now), with
    the side facing `toward_W` now turned towards the robot; its face's centre `touch_W`
    touches the table; `gain`: the expected share of the closed model newly seen (over the
    person's yaw error); `probability`: how often the model lands on that face when dropped;
    `overlap`: the expected share of what the pass sees that the passes before saw; `score`:
    the gain, less in proportion where the overlap is below `MIN_PASS_OVERLAP`."""

    down_W: np.ndarray
    touch_W: np.ndarray
    gain: float
    probability: float
    toward_W: np.ndarray
    overlap: float = 1.0
    score: float = 0.0


def next_best_face(
    seen: SeenSurface,
    centre_W: Sequence[float],
    radius_m: float,
    view_directions: np.ndarray,
    yaws: int = YAW_STEPS,
    yaw_error_rad: float = PERSON_YAW_ERROR_RAD,
) -> FaceChoice | None:
    """The stable face of the closed model to lay it on next, and the side to turn towards the
    robot (the same view directions, unit, from the centre; `yaws` headings tried, each scored
    over headings within `yaw_error_rad`); None when nothing is unseen or the model rests on
    no other face."""
    sight = unseen_sight(seen, centre_W, radius_m)
    if sight is None:
        return None
    again = seen_sight(seen, centre_W, radius_m)
    v, t = seen.surface.vertices, seen.surface.triangles
    com = centre_of_mass(v, t)
    poses = [p for p in resting_poses(v, com, MIN_MARGIN_M) if not _lies_on(p)]
    if not poses:
        # A round object's hull is slivers, none holding it 5 mm inside its edges (the teapot
        # on its side): the most probable faces still say which side to put down, and it
        # rolls onto the stable one nearest.
        poses = [p for p in resting_poses(v, com) if not _lies_on(p)]
    d = np.asarray(view_directions, float).reshape(-1, 3)
    step = 2 * math.pi / yaws
    within = int(yaw_error_rad // step)
    seen_count = int(seen.seen.sum())
    best: FaceChoice | None = None
    for pose in poses[:MAX_FACES]:
        R = pose.R_TO()
        # The face laid down touches the support: hidden from the pass, whatever it faces.
        support = SupportPlane(pose.centre_O, -pose.down_O)
        turns = [rotation_about(UP, j * step) @ R for j in range(yaws)]
        gains = np.array([sight.gain(d, T, support) for T in turns])
        # What a person turning it by eye gets: the headings within the error, alike.
        expected = _around(gains, within)
        # The share of what the pass sees that the passes before saw: what aligns it.
        new = expected * sight.total
        before = seen_count * _around(
            np.array([0.0 if again is None else again.gain(d, T, support) for T in turns]),
            within,
        )
        overlap = before / np.maximum(before + new, 1e-12)
        score = expected * np.minimum(overlap / MIN_PASS_OVERLAP, 1.0)
        # Of headings alike, the middle of them: a person's larger slip still shows it, and
        # the cameras see it squarely rather than grazing.
        alike = score >= score.max() - 1e-3
        j = int(np.argmax(np.where(alike, _around(gains, 2 * within), -1.0)))
        if best is None or score[j] > best.score:
            # The side that faces the robot once laid at heading j, as the object lies now.
            toward = R.T @ rotation_about(UP, -j * step) @ TOWARD_ROBOT
            best = FaceChoice(
                pose.down_O.copy(),
                pose.centre_O.copy(),
                float(expected[j]),
                pose.probability,
                toward,
                float(overlap[j]),
                float(score[j]),
            )
    return best


def _around(gains: np.ndarray, within: int) -> np.ndarray:
    """Per heading (a ring of them), the mean gain of those within `within` steps."""
    return np.mean([np.roll(gains, k) for k in range(-within, within + 1)], axis=0)


def _lies_on(pose) -> bool:
    """Whether the object lies on that face now."""
    return bool(pose.down_O @ -UP > math.cos(SAME_FACE_RAD))


def turn_deg(down_W: np.ndarray) -> float:
    """How far the object turns to bring `down_W` down."""
    return math.degrees(math.acos(float(np.clip(np.asarray(down_W) @ -UP, -1.0, 1.0))))


def face_words(down_W: np.ndarray) -> str:
    """The side facing `down_W` now, in words and as a direction in the cell frame."""
    a = np.asarray(down_W, float)
    return f"the side now facing {side_name(a)} (direction {a[0]:+.2f} {a[1]:+.2f} {a[2]:+.2f})"


def lay_instruction(
    choice: FaceChoice, index: int, picture: str | None, support: str = "table"
) -> str:
    """What the person is told for pass `index` (0-based), laying it on the `support`."""
    p = choice.touch_W
    seen_in = f" (see {picture})" if picture else ""
    return (
        f"pass {index + 1}: turn the object by about {turn_deg(choice.down_W):.0f} deg and lay "
        f"it on the {support} on {face_words(choice.down_W)}: the point now at x {p[0]:.3f}, "
        f"y {p[1]:.3f}, z {p[2]:.3f} m touches the {support}; put it down in the middle of the "
        f"{support}, turned so that {face_words(choice.toward_W)} faces the robot{seen_in}; "
        "then confirm"
    )

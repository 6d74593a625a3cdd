"""The next-best hanging: how to turn the object so that the next pass sees most of what the
passes so far have not.

Turning the object about its centre by R is, for what the cameras see, the same as turning the
cameras by R^T about it. So for a candidate "up" direction a (of the object as it hangs now),
the pass after the turn looks from c + r R^T d for each of the pass's view directions d, with
R the turn that brings a to the top followed by a yaw nobody controls (the operator may hang it
at any turn about the vertical): a candidate's gain is the share of the closed model's still
unseen samples those cameras would see, averaged over yaws. The clamp point is the model's
highest point after the turn: where the rod will hold it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from reconstruction.common.sphere import fibonacci_directions
from reconstruction.common.transforms import rotation_about, rotation_between
from reconstruction.evaluation.coverage import SeenSurface
from reconstruction.evaluation.metrics import SurfaceSamples, visibility
from reconstruction.evaluation.support import SupportPlane

UP = np.array([0.0, 0.0, 1.0])

# Candidate up directions (a Fibonacci sphere) and the yaws each is averaged over: finer grids
# change the chosen direction by less than the operator's own 10-25 deg error.
CANDIDATES = 48
YAWS = 4
GRID = 600


@dataclass(frozen=True)
class HangingChoice:
    """Bring `up_W` (unit, the object as it hangs now) to the top and clamp at `clamp_W`;
    `gain` is the expected share of the closed model newly seen."""

    up_W: np.ndarray
    clamp_W: np.ndarray
    gain: float


@dataclass(frozen=True, eq=False)
class Sight:
    """Which of a set of the closed model's samples (its unseen ones, `unseen_sight`; some of
    its seen ones, `seen_sight`) a camera would see from each of a fine grid of directions
    about the centre (`sees`: grid x those samples), cast once; `total`: the count the gains
    are shares of (every sample for the unseen, the subset for the seen)."""

    grid: np.ndarray
    sees: np.ndarray
    total: int
    points: np.ndarray | None = None  # (samples, 3): those samples, where they are now

    def gain(
        self, view_directions: np.ndarray, R: np.ndarray, support: SupportPlane | None = None
    ) -> float:
        """The share of the model newly seen by a pass of these view directions (unit, from
        the centre) after the object turned by R (3x3) about the centre; the cameras are looked
        up at their nearest grid direction (8 deg apart at most, finer than the operator's own
        error). `support`: the top the object will lie on in that pass (in the frame of the
        object now), which hides what lies on it."""
        return float(self.seen_by(view_directions, R, support).sum() / self.total)

    def seen_by(
        self, view_directions: np.ndarray, R: np.ndarray, support: SupportPlane | None = None
    ) -> np.ndarray:
        """Which unseen samples (bool per sample) those cameras would see."""
        nearest = np.argmax((view_directions @ R) @ self.grid.T, axis=1)  # rows: R^T d
        seen = self.sees[nearest].any(axis=0)
        if support is not None and self.points is not None:
            seen &= support.exposed(self.points)
        return seen


def unseen_sight(seen: SeenSurface, centre_W: Sequence[float], radius_m: float) -> Sight | None:
    """What the grid's cameras at `radius_m` from the centre would see of what is unseen; None
    when nothing is unseen."""
    return _sight(seen, ~seen.seen, centre_W, radius_m)


def seen_sight(
    seen: SeenSurface, centre_W: Sequence[float], radius_m: float, samples: int = 4000
) -> Sight | None:
    """The same of what was seen, on at most `samples` of those samples (`total`: their
    count, so that a share of it scales to all seen samples); None when nothing was seen."""
    index = np.flatnonzero(seen.seen)
    if len(index) > samples:
        index = np.sort(np.random.default_rng(0).choice(index, samples, replace=False))
    mask = np.zeros(len(seen.seen), bool)
    mask[index] = True
    sight = _sight(seen, mask, centre_W, radius_m)
    return None if sight is None else replace(sight, total=len(index))


def _sight(
    seen: SeenSurface, which: np.ndarray, centre_W: Sequence[float], radius_m: float
) -> Sight | None:
    if not which.any():
        return None
    c = np.asarray(centre_W, float)
    subset = SurfaceSamples(seen.samples.points[which], seen.samples.normals[which])
    grid = fibonacci_directions(GRID)
    sees = np.array(list(visibility(subset, seen.surface, c + radius_m * grid)))
    return Sight(grid, sees, len(seen.seen), subset.points)


def next_best_hanging(
    seen: SeenSurface,
    centre_W: Sequence[float],
    radius_m: float,
    view_directions: np.ndarray,
    candidates: int = CANDIDATES,
    yaws: int = YAWS,
) -> HangingChoice | None:
    """The turn of the object whose next pass (the same view directions, unit, from the
    centre) newly sees the most of `seen`'s unseen samples; None when nothing is unseen."""
    sight = unseen_sight(seen, centre_W, radius_m)
    if sight is None:
        return None
    c = np.asarray(centre_W, float)
    d = np.asarray(view_directions, float).reshape(-1, 3)
    best: HangingChoice | None = None
    for a in fibonacci_directions(candidates):
        R_up = rotation_between(a, UP)
        gain = 0.0
        for j in range(yaws):
            gain += sight.gain(d, rotation_about(UP, 2 * math.pi * j / yaws) @ R_up) / yaws
        if best is None or gain > best.gain:
            best = HangingChoice(a, _clamp_point(seen, a, c), float(gain))
    return best


def _clamp_point(seen: SeenSurface, up_W: np.ndarray, centre_W: np.ndarray) -> np.ndarray:
    """The closed model's highest point once `up_W` points up."""
    v = seen.surface.vertices
    return v[int(np.argmax((v - centre_W) @ up_W))]


def side_name(vector: np.ndarray) -> str:
    """Where a direction points in the cell, in words (the robot stands at the origin, the
    object in front of it along +x)."""
    x, y, z = vector
    parts = []
    if abs(z) > 0.3:
        parts.append("down" if z < 0 else "up")
    if abs(x) > 0.3:
        parts.append("towards the robot" if x < 0 else "away from the robot")
    if abs(y) > 0.3:
        parts.append("to the robot's left" if y > 0 else "to the robot's right")
    return " and ".join(parts) or "sideways"


def instruction(choice: HangingChoice, hanging: int, picture: str | None) -> str:
    """What the operator is told for pass `hanging` (0-based)."""
    a, p = choice.up_W, choice.clamp_W
    turn = math.degrees(math.acos(float(np.clip(a @ UP, -1.0, 1.0))))
    seen_in = f" (see {picture})" if picture else ""
    return (
        f"hanging {hanging + 1}: turn the object by about {turn:.0f} deg so that the side now "
        f"facing {side_name(a)} (direction {a[0]:+.2f} {a[1]:+.2f} {a[2]:+.2f} in the cell frame) "
        f"points straight up; clamp it there, at the point now at x {p[0]:.3f}, y {p[1]:.3f}, "
        f"z {p[2]:.3f} m, and hang it with its middle where it was{seen_in}; then confirm"
    )

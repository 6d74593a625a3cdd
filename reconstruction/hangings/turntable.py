"""Known turns: passes of an object on a turntable, turned by angles the turntable reports.

The object turns rigidly about the turntable's axis (a point p_W on it, unit direction u_W):
a point seen at p in the pass at angle a was at Rot(u, -(a - a0)) about the axis in the pass at
a0. That transform is the starting guess of the pass alignment; the alignment refines it (the
axis is only nominal until calibrated, and a turntable's encoder has its own error) and
verifies it as any other pass.

The axis is calibrated from the verified alignments of the first turns: each is a rotation
about the true axis, whose direction is the rotation's axis and whose points p solve
(I - R) p = t; several turns, stacked, fix it in least squares.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.transforms import make_pose, matrix_to_rotvec, rotation_about

# A turn smaller than this tells nothing about where the axis is (I - R is near zero).
MIN_CALIBRATION_TURN_RAD = np.radians(10.0)


def turn_about_axis(p_W: np.ndarray, u_W: np.ndarray, angle_rad: float) -> np.ndarray:
    """The 4x4 rigid transform that turns points by `angle_rad` about the axis through p_W
    along u_W (right hand)."""
    R = rotation_about(np.asarray(u_W, float), angle_rad)
    p = np.asarray(p_W, float)
    return make_pose(R, p - R @ p)


@dataclass(frozen=True, eq=False)
class Axis:
    """A turntable's axis: a point on it and its unit direction (world frame, metres)."""

    p_W: np.ndarray
    u_W: np.ndarray


def axis_from_turns(turns: Sequence[np.ndarray], p_near_W: np.ndarray) -> Axis | None:
    """The axis about which the rigid transforms `turns` (4x4) rotate, with the point on it
    nearest `p_near_W`; None when no turn is large enough to tell."""
    rotvecs = [matrix_to_rotvec(T[:3, :3]) for T in turns]
    used = [(T, w) for T, w in zip(turns, rotvecs) if np.linalg.norm(w) > MIN_CALIBRATION_TURN_RAD]
    if not used:
        return None
    # Directions of turns of either sense: all made to agree with the first before averaging.
    u = np.zeros(3)
    for _, w in used:
        w = w / np.linalg.norm(w)
        u += w if w @ (u if u.any() else w) >= 0 else -w
    u /= np.linalg.norm(u)
    A = np.vstack([np.eye(3) - T[:3, :3] for T, _ in used] + [u[None, :]])
    b = np.concatenate([T[:3, 3] for T, _ in used] + [[u @ np.asarray(p_near_W, float)]])
    p = np.linalg.lstsq(A, b, rcond=None)[0]
    return Axis(p, u)


@dataclass(frozen=True, eq=False)
class KnownTurns:
    """The angle (rad) the turntable reported in each pass, and its nominal axis (the cell
    model's: vertical through the turntable's centre). `turned_passes`: how many passes, from
    the first, only the turntable moved the object (None: all); from the first pass laid on
    another face on, the object's pose is the person's, not a known turn."""

    angles_rad: tuple[float, ...]
    nominal: Axis
    turned_passes: int | None = None

    def known(self, hanging: int) -> bool:
        """Whether pass `hanging` stands where a known turn put it."""
        return self.turned_passes is None or hanging < self.turned_passes

    def start(
        self, hanging: int, verified: Sequence[tuple[int, np.ndarray]] = ()
    ) -> np.ndarray | None:
        """The guess of pass `hanging`'s transform onto pass 0, about the axis calibrated from
        the `verified` alignments so far ((pass, T) pairs), else the nominal axis; None for a
        pass laid anew (or after one): no turn is known."""
        if not self.known(hanging):
            return None
        axis = self.calibrated(verified)
        turned = self.angles_rad[hanging] - self.angles_rad[0]
        return turn_about_axis(axis.p_W, axis.u_W, -turned)

    def calibrated(self, verified: Sequence[tuple[int, np.ndarray]] = ()) -> Axis:
        """The axis from the verified alignments (nominal where they cannot tell), its
        direction in the sense of the nominal one."""
        found = axis_from_turns([T for h, T in verified if self.known(h)], self.nominal.p_W)
        if found is None:
            return self.nominal
        u = found.u_W if found.u_W @ self.nominal.u_W >= 0 else -found.u_W
        return Axis(found.p_W, u)

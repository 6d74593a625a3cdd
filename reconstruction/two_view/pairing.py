"""Which views make stereo pairs: each view and its nearest usable neighbour(s).

One camera on an arm sees the object from many poses; two neighbouring poses are a stereo rig
whose baseline the arm provides. A pair needs enough baseline for depth resolution (the
depth error grows as distance^2 / (f b)) and little enough change of viewpoint that SGBM's
window still sees the same surface patch from both sides: the optical axes' angle and the
baseline relative to the working distance bound both. Among the usable partners the nearest
are best (they see the most surface in common): on a scan path those are the arm's
neighbouring positions, above and below as well as left and right (pair rectification turns
a vertical pair into a horizontal one, `two_view.rectification`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import check_pose


@dataclass(frozen=True)
class PairingConfig:
    """Limits of a usable pair. The baseline is relative to the reference camera's distance to
    the working volume's centre (b / z, what sets the depth resolution f b / z^2 per pixel).

    Defaults: DTU's robot positions are 0.12 m and about 10 deg apart at 0.65 m (b / z 0.18);
    the product's own stereo rig has b / z 0.24 (0.12 m at 0.5 m). Below 4 deg or b / z 0.05
    a disparity pixel spans more than 1 % of the depth at DTU's focal length; beyond 25 deg
    and b / z 0.45 the two views of a curved surface differ too much for block matching.
    """

    min_angle_rad: float = positive(math.radians(4.0))
    max_angle_rad: float = positive(math.radians(25.0), at_most=math.pi)
    min_baseline_ratio: float = positive(0.05)
    max_baseline_ratio: float = positive(0.45)
    # Each view is the reference of this many pairs (its nearest usable partners).
    pairs_per_view: int = integer(1, minimum=1)

    def __post_init__(self) -> None:
        check_fields("pairing", self)
        if not self.min_angle_rad < self.max_angle_rad:
            raise ScannerError(
                f"pairing.min_angle_rad: must be below max_angle_rad ({self.max_angle_rad}), "
                f"got {self.min_angle_rad}"
            )
        if not self.min_baseline_ratio < self.max_baseline_ratio:
            raise ScannerError(
                f"pairing.min_baseline_ratio: must be below max_baseline_ratio "
                f"({self.max_baseline_ratio}), got {self.min_baseline_ratio}"
            )


@dataclass(frozen=True)
class ViewPair:
    """Views `reference` (whose frame C the pair's cloud is expressed in) and `other`, indices
    into the list given to `pair_views`; their camera centres' distance and optical axes' angle."""

    reference: int
    other: int
    baseline_m: float
    angle_rad: float


def _limit_broken(angle_rad: float, ratio: float, config: PairingConfig) -> str | None:
    """The name and bound of the first limit a candidate breaks, None when within all."""
    checks = (
        ("min_angle_rad", angle_rad, "<", config.min_angle_rad),
        ("max_angle_rad", angle_rad, ">", config.max_angle_rad),
        ("min_baseline_ratio", ratio, "<", config.min_baseline_ratio),
        ("max_baseline_ratio", ratio, ">", config.max_baseline_ratio),
    )
    for name, value, relation, bound in checks:
        if (value < bound) if relation == "<" else (value > bound):
            return f"pairing.{name} ({value:.4g} {relation} {bound:.4g})"
    return None


def pair_views(
    X_WC: Sequence[np.ndarray], p_W_centre: np.ndarray, config: PairingConfig
) -> tuple[ViewPair, ...]:
    """Each view as the reference of its `config.pairs_per_view` nearest partners within the
    limits, in view order, nearest partner first.

    X_WC: camera poses (4x4, metres); p_W_centre: the working volume's centre (3,) in W.
    A view without any usable partner is a ScannerError naming the limit its nearest
    neighbour breaks (a scan whose views cannot all be paired is not what was planned).
    """
    poses = [check_pose(X, f"view {i}: X_WC") for i, X in enumerate(X_WC)]
    if len(poses) < 2:
        raise ScannerError(f"pairing: need at least 2 views, got {len(poses)}")
    p_W_centre = np.asarray(p_W_centre, float).reshape(3)
    p_W_eyes = np.array([X[:3, 3] for X in poses])
    z_W = np.array([X[:3, 2] for X in poses])  # optical axes in W
    distances_m = np.linalg.norm(p_W_centre - p_W_eyes, axis=1)
    for i, X in enumerate(poses):
        if (p_W_centre - X[:3, 3]) @ X[:3, 2] <= 0:
            raise ScannerError(
                f"pairing: the working volume's centre {p_W_centre.tolist()} m is behind view {i}"
            )
    baselines_m = np.linalg.norm(p_W_eyes[:, None] - p_W_eyes[None], axis=2)
    angles_rad = np.arccos(np.clip(z_W @ z_W.T, -1.0, 1.0))
    pairs = []
    for i in range(len(poses)):
        others = [j for j in np.argsort(baselines_m[i], kind="stable") if j != i]
        usable = [
            int(j)
            for j in others
            if _limit_broken(angles_rad[i, j], baselines_m[i, j] / distances_m[i], config) is None
        ]
        if not usable:
            j = int(others[0])
            broken = _limit_broken(angles_rad[i, j], baselines_m[i, j] / distances_m[i], config)
            raise ScannerError(
                f"pairing: view {i} has no partner within the limits; its nearest view {j} "
                f"({baselines_m[i, j]:.3f} m away) breaks {broken}"
            )
        for j in usable[: config.pairs_per_view]:
            pairs.append(ViewPair(i, j, float(baselines_m[i, j]), float(angles_rad[i, j])))
    return tuple(pairs)

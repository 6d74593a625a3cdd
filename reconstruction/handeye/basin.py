"""A rough mount's hand-eye transform, found before pairwise registration: the joint cloud fit
(`handeye_refine`) run coarse (thinned clouds, a redescending loss, gates from 80 mm down) on
pairs chosen by viewing direction alone, which does not depend on X_FC.

Why first. Pairwise ICP starts from the kinematic poses X_WF_i @ X_FC; a mount 25 mm / 6 deg
off puts neighbouring views tens of millimetres apart, beyond ICP's gates, the pose graph prunes
the edges and the correction has nothing to stand on. The one shared X_FC, fitted over all
pairs at once, has a far wider basin: on the 24-view bunny it came back from 60 mm / 15 deg to
0.2 mm / 0.05 deg in ~25 Gauss-Newton steps (2-5 s), and the normal pipeline then starts
from there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from reconstruction.common.checks import require_count, require_positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import pose_difference, twist_to_pose
from reconstruction.handeye.refine import (
    CloudFit,
    HandEyeRefinement,
    RefineLevel,
    check_fit_settings,
    refine_on_clouds,
)
from reconstruction.registration.filtering import FilteredCloud


def _default_coarse_levels() -> tuple[RefineLevel, ...]:
    # 80 mm holds a 60 mm / 15 deg mount error between neighbouring views; halving the gate
    # each level drops the wrong matches as the views come together.
    return (RefineLevel(0.08, 8), RefineLevel(0.04, 8), RefineLevel(0.02, 8), RefineLevel(0.01, 8))


@dataclass(frozen=True)
class CoarseHandEyeConfig:
    """The coarse hand-eye stage (`handeye.coarse`; lengths in metres).

    pair_angle_rad: views whose optical axes are within this angle are paired. A Cauchy loss
    (redescending: far matches stop pulling) at `loss_scale_m`. refilter_above_m: when the
    coarse X_FC moves points at the working distance by more than this, the views are cropped
    and cleaned again at the new poses (the region of interest and the robot's own points are
    placed in W)."""

    enabled: bool = True
    pair_angle_rad: float = math.radians(50.0)
    levels: tuple[RefineLevel, ...] = field(default_factory=_default_coarse_levels)
    voxel_size_m: float = 0.004
    target_voxel_size_m: float = 0.002
    max_points_per_view: int = 300
    loss: str = "cauchy"
    loss_scale_m: float = 0.002
    refilter_above_m: float = 0.02
    # A fit that leaves fewer than this share of points matched at the last gate is in a wrong
    # basin (measured on the bunny: right fits 0.89, a wrong one from 20 mm / 15 deg 0.60);
    # then the fit is started again from the nominal X_FC turned by restart_angle_rad about
    # each axis of C, both ways, and the best match fraction wins.
    good_match_fraction: float = 0.8
    restart_angle_rad: float = math.radians(10.0)
    # The stage runs only when fewer than this share of the pairs registered at the nominal
    # mount pass their edge checks: a mount within ICP's reach needs no rough search (on the
    # default scans 93 of 94 pairs pass; a 25 mm / 6 deg mount fails most of them).
    skip_when_pairs_hold: float = 0.8

    def __post_init__(self) -> None:
        check_fit_settings(self.loss, "handeye.coarse.loss", self.levels, "handeye.coarse.levels")
        require_positive(
            "handeye.coarse",
            self,
            (
                "pair_angle_rad",
                "voxel_size_m",
                "target_voxel_size_m",
                "loss_scale_m",
                "refilter_above_m",
                "restart_angle_rad",
            ),
        )
        if not 0.0 <= self.skip_when_pairs_hold <= 1.0:
            raise ScannerError(
                "handeye.coarse.skip_when_pairs_hold: must be within 0..1, got "
                f"{self.skip_when_pairs_hold}"
            )
        if not 0.0 <= self.good_match_fraction <= 1.0:
            raise ScannerError(
                "handeye.coarse.good_match_fraction: must be within 0..1, got "
                f"{self.good_match_fraction}"
            )
        require_count("handeye.coarse", self, ("max_points_per_view",), minimum=10)

    def fit(self, seed: int) -> CloudFit:
        return CloudFit(
            self.levels,
            self.voxel_size_m,
            self.target_voxel_size_m,
            self.max_points_per_view,
            self.loss,
            self.loss_scale_m,
            1e-5,
            1e-5,
            seed,
        )


def direction_pairs(
    X_WC: Sequence[np.ndarray], groups: Sequence[Sequence[int]], max_angle_rad: float
) -> list[tuple[int, int]]:
    """Pairs of views (list positions) of the same hanging whose optical axes are within
    `max_angle_rad`: every view aims at the scan centre, so this is overlap whatever X_FC is."""
    pairs = []
    for group in groups:
        z = np.array([X_WC[k][:3, 2] for k in group])
        angle = np.arccos(np.clip(z @ z.T, -1.0, 1.0))
        pairs += [
            (group[a], group[b])
            for a in range(len(group))
            for b in range(a + 1, len(group))
            if angle[a, b] <= max_angle_rad
        ]
    return pairs


def displacement_at(X_a: np.ndarray, X_b: np.ndarray, distance_m: float) -> float:
    """How far two hand-eye transforms place a point at `distance_m` apart (at most)."""
    dt, dr = pose_difference(X_a, X_b)
    return dt + distance_m * dr


def coarse_handeye(
    clouds: Sequence[FilteredCloud],
    X_WF: Sequence[np.ndarray],
    groups: Sequence[Sequence[int]],
    X_FC_nominal: np.ndarray,
    config: CoarseHandEyeConfig,
    seed: int = 0,
) -> HandEyeRefinement | None:
    """X_FC from a rough start (restarted from turned starts when the fit is poor); None when
    no two views overlap."""
    X_WC = [X @ X_FC_nominal for X in X_WF]
    pairs = direction_pairs(X_WC, groups, config.pair_angle_rad)
    if not pairs:
        return None
    best = refine_on_clouds(clouds, X_WF, pairs, X_FC_nominal, config.fit(seed))
    for axis in range(6):
        if best.match_fraction >= config.good_match_fraction:
            break
        twist = np.zeros(6)
        twist[axis // 2] = config.restart_angle_rad * (1 if axis % 2 == 0 else -1)
        start = X_FC_nominal @ twist_to_pose(twist)
        try:
            fit = refine_on_clouds(clouds, X_WF, pairs, start, config.fit(seed))
        except ScannerError:
            # A turned start can carry the views apart until nothing overlaps: a failed
            # restart, not a failed reconstruction (the fit from the nominal start stands).
            continue
        if fit.match_fraction > best.match_fraction:
            best = fit
    return best

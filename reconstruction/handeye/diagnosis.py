"""Did the hand-eye correction converge? Judged without truth, from figures the scan has:

- match fraction: the share of thinned source points that find a surface within the finest
  gate in the overlapping views at the final X_FC (views that agree overlap where they should);
- match RMS: those matches' point-to-plane distance, against the stereo noise;
- AX = XB agreement: OpenCV's solver on the motions that pairwise ICP and the pose graph found
  (they do not use the clouds' joint fit) against the final X_FC;
- last change: how far the last round's fit moved X_FC from where that round's registration
  started (the coarse answer or the round before): registration and correction must agree.

A wrong X_FC leaves the views apart (few matches, large RMS) and the ICP motions disagree with
it; a right one passes all four.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruction.common.checks import require_fraction, require_positive
from reconstruction.common.transforms import pose_difference
from reconstruction.handeye.refine import HandEyeRefinement


@dataclass(frozen=True)
class ConvergenceLimits:
    """`handeye.convergence`: the limits the figures must meet (lengths in metres)."""

    min_match_fraction: float = 0.5
    max_match_rms_m: float = 0.0008
    max_axxb_disagreement_m: float = 0.003
    max_axxb_disagreement_rad: float = math.radians(0.5)
    max_last_change_m: float = 0.003
    max_last_change_rad: float = math.radians(0.5)

    def __post_init__(self) -> None:
        require_fraction("handeye.convergence", self, ("min_match_fraction",))
        require_positive(
            "handeye.convergence",
            self,
            (
                "max_match_rms_m",
                "max_axxb_disagreement_m",
                "max_axxb_disagreement_rad",
                "max_last_change_m",
                "max_last_change_rad",
            ),
        )


@dataclass(frozen=True)
class HandEyeDiagnosis:
    """The figures (NaN: not available) and the checks that failed (empty: converged)."""

    match_fraction: float
    match_rms_m: float
    axxb_disagreement_m: float
    axxb_disagreement_rad: float
    last_change_m: float
    last_change_rad: float
    failures: tuple[str, ...]

    @property
    def converged(self) -> bool:
        return not self.failures


def diagnose(
    X_FC: np.ndarray,
    refinement: HandEyeRefinement | None,
    X_FC_axxb: np.ndarray | None,
    X_FC_round_start: np.ndarray | None,
    limits: ConvergenceLimits,
) -> HandEyeDiagnosis:
    """The diagnosis of a final X_FC from the fine fit, the AX = XB answer and the X_FC the
    last round started from (each None when that step did not run)."""
    failures = []
    nan = math.nan
    fraction, rms = (
        (nan, nan)
        if refinement is None
        else (
            refinement.match_fraction,
            refinement.rms_after_m,
        )
    )
    if refinement is None:
        failures.append("no joint fit of X_FC on the clouds (no overlapping views)")
    else:
        if not fraction >= limits.min_match_fraction:
            failures.append(
                f"only {100 * fraction:.0f} % of the points meet the overlapping views "
                f"(need >= {100 * limits.min_match_fraction:.0f} %)"
            )
        if not rms <= limits.max_match_rms_m:
            failures.append(
                f"match RMS {1e3 * rms:.2f} mm (limit {1e3 * limits.max_match_rms_m:g} mm)"
            )
    axxb_t = axxb_r = nan
    if X_FC_axxb is not None and np.all(np.isfinite(X_FC_axxb)):
        axxb_t, axxb_r = pose_difference(X_FC_axxb, X_FC)
        if axxb_t > limits.max_axxb_disagreement_m or axxb_r > limits.max_axxb_disagreement_rad:
            failures.append(
                f"AX = XB on the registered motions disagrees by {1e3 * axxb_t:.1f} mm / "
                f"{math.degrees(axxb_r):.2f} deg (limit {1e3 * limits.max_axxb_disagreement_m:g}"
                f" mm / {math.degrees(limits.max_axxb_disagreement_rad):g} deg)"
            )
    change_t = change_r = nan
    if X_FC_round_start is not None:
        change_t, change_r = pose_difference(X_FC_round_start, X_FC)
        if change_t > limits.max_last_change_m or change_r > limits.max_last_change_rad:
            failures.append(
                f"the last round moved X_FC by {1e3 * change_t:.1f} mm / "
                f"{math.degrees(change_r):.2f} deg: registration and correction do not agree yet"
                " (limit "
                f"{1e3 * limits.max_last_change_m:g} mm / "
                f"{math.degrees(limits.max_last_change_rad):g} deg)"
            )
    return HandEyeDiagnosis(fraction, rms, axxb_t, axxb_r, change_t, change_r, tuple(failures))

"""Did the hand-eye correction converge? Judged without truth, from figures the scan has:

- match fraction: the share of thinned source points that find a surface within the finest
  gate in the overlapping views at the final X_FC (views that agree overlap where they should);
- match RMS: those matches' point-to-plane distance, against the stereo noise;
- AX = XB agreement: OpenCV's solver on the motions that pairwise ICP and the pose graph found
  (they do not use the clouds' joint fit) against the final X_FC;
- last change: how far the last round's fit moved X_FC from where that round's registration
  started (the coarse answer or the round before): registration and correction must agree.

- stated accuracy: the fit's own sigma (`HandEyeRefinement.sigma_translation_m`, from how much
  X_FC depends on each view), never better than half the AX = XB disagreement, must exist and
  be within the limits, and the fit's last step must be small against it (a fit still moving
  by its stated sigma has not reached what it states).

A wrong X_FC leaves the views apart (few matches, large RMS) and the ICP motions disagree with
it; a right one passes all four. "Converged" also claims the stated sigma: a correction whose
views cannot pin X_FC down to the limits, or that cannot say how well, is not converged, however
well its views meet.
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
    # The largest stated accuracy (RMS error of the camera's origin / orientation) a converged
    # correction may have: 3 sigma of 1 mm / 0.3 deg is about the mount error a scan starts
    # from (a hand-made mount: 3 mm / 1 deg), so a correction that cannot state better has not
    # shown that it improved on it.
    max_sigma_m: float = 0.001
    max_sigma_rad: float = math.radians(0.3)
    # The fit's last step, as a share of its stated sigma: a fit still moving by a good part
    # of what it claims has not reached it.
    max_last_step_sigmas: float = 0.5

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
                "max_sigma_m",
                "max_sigma_rad",
                "max_last_step_sigmas",
            ),
        )


@dataclass(frozen=True)
class HandEyeDiagnosis:
    """The figures (NaN: not available) and the checks that failed (empty: converged).
    `sigma_translation_m` / `sigma_rotation_rad`: the accuracy the correction states (the
    fine fit's, see `HandEyeRefinement`, never better than half the AX = XB disagreement)."""

    match_fraction: float
    match_rms_m: float
    axxb_disagreement_m: float
    axxb_disagreement_rad: float
    last_change_m: float
    last_change_rad: float
    failures: tuple[str, ...]
    sigma_translation_m: float = math.nan
    sigma_rotation_rad: float = math.nan

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
    sigma_t = sigma_r = nan
    if refinement is not None and not np.allclose(refinement.X_FC, X_FC, rtol=0, atol=1e-12):
        # Kept the nominal or the AX = XB answer (the fit was beyond the sanity limits): the
        # fit's sigma is not the accuracy of the X_FC in use, and nothing else states one.
        failures.append("the X_FC in use is not the joint fit's: its accuracy is not stated")
    elif refinement is not None:
        # Two estimates that disagree by d cannot both be closer than d / 2 to the truth, so
        # the stated accuracy is never better than half the disagreement with AX = XB (an
        # estimate from the ICP motions, not from the joint fit). The jackknife does not see an
        # error a whole hanging shares; AX = XB did: a 2 x 10-view bunny scan at 640x480, true
        # error 0.79 mm / 0.097 deg, jackknife 0.15 mm / 0.023 deg, AX = XB off by 0.86 mm /
        # 0.082 deg.
        sigma_t = _at_least(refinement.sigma_translation_m, axxb_t / 2)
        sigma_r = _at_least(refinement.sigma_rotation_rad, axxb_r / 2)
        failures += _accuracy_failures(sigma_t, sigma_r, refinement, limits)
    return HandEyeDiagnosis(
        fraction, rms, axxb_t, axxb_r, change_t, change_r, tuple(failures), sigma_t, sigma_r
    )


def _at_least(sigma: float, floor: float) -> float:
    """`sigma` raised to `floor` (a NaN floor, from a step that did not run, raises nothing;
    a NaN sigma stays NaN)."""
    return max(sigma, floor) if np.isfinite(floor) else sigma


def _accuracy_failures(
    sigma_t: float, sigma_r: float, refinement: HandEyeRefinement, limits: ConvergenceLimits
) -> list[str]:
    """The stated accuracy's checks: it exists, it is within the limits, and the fit is not
    still moving by a good part of it."""
    if not (np.isfinite(sigma_t) and np.isfinite(sigma_r)):
        return ["the fit cannot state its accuracy (too few views, or one view holds it up)"]
    failures = []
    if sigma_t > limits.max_sigma_m or sigma_r > limits.max_sigma_rad:
        failures.append(
            f"the views pin X_FC down to {1e3 * sigma_t:.2f} mm / {math.degrees(sigma_r):.3f} deg"
            f" only (sigma; limit {1e3 * limits.max_sigma_m:g} mm / "
            f"{math.degrees(limits.max_sigma_rad):g} deg)"
        )
    k = limits.max_last_step_sigmas
    if refinement.last_step_m > k * sigma_t or refinement.last_step_rad > k * sigma_r:
        failures.append(
            f"the fit was still moving X_FC by {1e3 * refinement.last_step_m:.3f} mm / "
            f"{math.degrees(refinement.last_step_rad):.4f} deg a step when it stopped "
            f"(limit {k:g} x its sigma)"
        )
    return failures

"""Hand-eye correction from the scan itself: AX = XB on the refined motions, then a joint
refinement of the one shared X_FC directly on the clouds.

Why both. AX = XB (OpenCV's solvers) needs only poses and is a good start, but it inherits the
pose graph's errors. The hand-eye error is the SAME transform in every view, so the clouds
themselves pin it down: with X_WC_i = X_WF_i @ X_FC, overlapping views agree only for the right
X_FC (the views differ in orientation, so each view turns an X_FC error into a different shift in
W). Estimating those 6 parameters from all overlaps at once has no gauge freedom and no anchor
view, which is what recovered the hand-eye to 0.27 mm / 0.017 deg in a prototype of this pipeline
(24 views of a 0.2 m bunny at 0.5 m, mount error 3 mm / 1 deg; the pose graph alone kept 3 mm).

Measured on synthetic 24-view scans over the RX60's band (0.3 mm depth noise, per-view flange
errors of 0.05 mm / 0.005 deg, X_FC off by 3 mm / 1 deg): AX = XB (Park) 0.11-0.40 mm /
0.03-0.08 deg; the refinement 0.05-0.16 mm / 0.003-0.02 deg on the bunny and the bracket, but
0.3-0.8 mm / 0.07-0.18 deg on the round pebble (see `HandEyeRefinement.weakest_mode`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from reconstruction.calibration.hand_eye import HAND_EYE_METHODS, HandEyeMethodError, solve_hand_eye
from reconstruction.common.checks import require_choice, require_count, require_positive
from reconstruction.common.transforms import invert, mean_pose, pose_difference, snapped
from reconstruction.handeye.basin import CoarseHandEyeConfig
from reconstruction.handeye.diagnosis import ConvergenceLimits, HandEyeDiagnosis, diagnose
from reconstruction.handeye.refine import (
    CloudFit,
    HandEyeRefinement,
    RefineLevel,
    check_fit_settings,
    refine_on_clouds,
)
from reconstruction.registration.filtering import FilteredCloud


def _default_refine_levels() -> tuple[RefineLevel, ...]:
    # 15 mm covers a 3 mm / 1 deg hand-eye error (up to ~11 mm between views); then tighten to
    # a few times the stereo noise so that wrong matches at the rims drop out. The wide gates
    # only bring X_FC into the last one's basin, which a quarter of the points does as well as
    # all of them; the last gate, where the answer and its stated accuracy come from, matches
    # every point.
    return (RefineLevel(0.015, 6, 250), RefineLevel(0.005, 6, 250), RefineLevel(0.002, 20))


@dataclass(frozen=True)
class HandEyeConfig:
    enabled: bool = True
    axxb_method: str = "park"  # Park-Martin: closed form, least squares over all motion pairs
    # A view whose AX = XB residual exceeds these (and 3x the median) is left out, then solved
    # again, at most `axxb_max_rejection_rounds` times.
    axxb_outlier_translation_m: float = 0.002
    axxb_outlier_rotation_rad: float = math.radians(0.2)
    axxb_max_rejection_rounds: int = 3
    refine: bool = True
    refine_levels: tuple[RefineLevel, ...] = field(default_factory=_default_refine_levels)
    # Sources are thinned to this voxel and capped per view: 6 unknowns need far fewer
    # correspondences than ICP does, and the cost is linear in them.
    refine_voxel_size_m: float = 0.002
    refine_max_points_per_view: int = 1000
    # Targets keep more detail for the tangent planes (normals come from the filter stage).
    refine_target_voxel_size_m: float = 0.001
    refine_loss: str = "huber"
    refine_loss_scale_m: float = 0.0005  # ~2x the stereo noise: beyond it, a match is suspect
    # A step below these (10 um, 0.0006 deg) is 50x under the targets (0.5 mm, 0.1 deg).
    refine_tolerance_m: float = 1e-5
    refine_tolerance_rad: float = 1e-5
    # Sanity limits: a correction larger than this is not trusted (a hand-made mount is
    # within a few centimetres and degrees; beyond, the scan probably lacks the rotations that
    # make X_FC observable).
    max_correction_m: float = 0.1
    max_correction_rad: float = math.radians(20.0)
    seed: int = 0
    coarse: CoarseHandEyeConfig = field(default_factory=CoarseHandEyeConfig)
    # Rounds of registration + correction, until X_FC moves points at the working distance by
    # at most round_tolerance_m: ICP's first gate (15 mm) absorbs a start a few millimetres off,
    # so another round (a whole registration, ~30 s for 48 views) only pays beyond that.
    max_rounds: int = 3
    round_tolerance_m: float = 0.003
    convergence: ConvergenceLimits = field(default_factory=ConvergenceLimits)

    def __post_init__(self) -> None:
        require_choice("handeye", "axxb_method", self.axxb_method, HAND_EYE_METHODS)
        check_fit_settings(
            self.refine_loss, "handeye.refine_loss", self.refine_levels, "handeye.refine_levels"
        )
        require_positive(
            "handeye",
            self,
            (
                "axxb_outlier_translation_m",
                "axxb_outlier_rotation_rad",
                "refine_voxel_size_m",
                "refine_target_voxel_size_m",
                "refine_loss_scale_m",
                "refine_tolerance_m",
                "refine_tolerance_rad",
                "max_correction_m",
                "max_correction_rad",
                "round_tolerance_m",
            ),
        )
        require_count("handeye", self, ("max_rounds",))
        require_count("handeye", self, ("refine_max_points_per_view",), minimum=10)
        require_count("handeye", self, ("axxb_max_rejection_rounds", "seed"), minimum=0)

    @property
    def fine_fit(self) -> CloudFit:
        return CloudFit(
            self.refine_levels,
            self.refine_voxel_size_m,
            self.refine_target_voxel_size_m,
            self.refine_max_points_per_view,
            self.refine_loss,
            self.refine_loss_scale_m,
            self.refine_tolerance_m,
            self.refine_tolerance_rad,
            self.seed,
        )


@dataclass(frozen=True, eq=False)
class AxxbSolution:
    """One AX = XB solver's X_FC and its consistency: RMS over the used views of the
    disagreement between X_WF_i @ X_FC and the refined camera make_pose (after the best common
    world offset), and the views left out as outliers (list positions)."""

    method: str
    X_FC: np.ndarray
    rms_translation_m: float
    rms_rotation_rad: float
    used_views: tuple[int, ...]
    rejected_views: tuple[int, ...]
    error: str = ""  # the solver's failure message; X_FC is then all NaN


@dataclass(frozen=True, eq=False, kw_only=True)
class HandEyeResult:
    """What the correction decided: X_FC used downstream, its change from the nominal one,
    every AX = XB solver's answer, the refinement (if run), and notes on what was not trusted."""

    X_FC_nominal: np.ndarray
    X_FC: np.ndarray
    change_translation_m: float
    change_rotation_rad: float
    axxb: dict[str, AxxbSolution]
    refinement: HandEyeRefinement | None
    source: str  # "nominal", "coarse", "axxb:<method>" or "refined"
    notes: tuple[str, ...]
    coarse: HandEyeRefinement | None
    diagnosis: HandEyeDiagnosis


def _axxb_residuals(
    X_WF: Sequence[np.ndarray], X_WC: Sequence[np.ndarray], X_FC: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-view (translation m, rotation rad) between X_WF_i @ X_FC and the refined camera pose
    moved by the best common offset (the refined poses' world is only defined up to one)."""
    X_pred = [X_WF[i] @ X_FC for i in range(len(X_WF))]
    X_offset = mean_pose([X_pred[i] @ invert(X_WC[i]) for i in range(len(X_WF))])
    d = np.array([pose_difference(X_pred[i], X_offset @ X_WC[i]) for i in range(len(X_WF))])
    return d[:, 0], d[:, 1]


def solve_axxb(
    X_WF: Sequence[np.ndarray], X_WC: Sequence[np.ndarray], method: str, config: HandEyeConfig
) -> AxxbSolution:
    """AX = XB over all views with the pose graph's world as the fixed target, leaving out
    views that disagree with the answer."""
    used = list(range(len(X_WF)))
    rejected: list[int] = []
    X_FC = np.eye(4)
    for round_ in range(config.axxb_max_rejection_rounds + 1):
        try:
            X_FC = solve_hand_eye([X_WF[i] for i in used], [invert(X_WC[i]) for i in used], method)
        except HandEyeMethodError as e:
            # Some solvers fail on near-degenerate motion sets (seen: Andreff, "determinant(R)
            # is null"); the others still answer, so this is a result, not an exception.
            nan = np.full((4, 4), np.nan)
            return AxxbSolution(method, nan, math.nan, math.nan, tuple(used), (), str(e))
        dt, dr = _axxb_residuals([X_WF[i] for i in used], [X_WC[i] for i in used], X_FC)
        if round_ == config.axxb_max_rejection_rounds or len(used) <= 3:
            break
        # Outliers against both an absolute bound and the bulk, so a uniformly noisy scan
        # does not lose its views.
        bad = (dt > max(config.axxb_outlier_translation_m, 3 * np.median(dt))) | (
            dr > max(config.axxb_outlier_rotation_rad, 3 * np.median(dr))
        )
        if not bad.any() or len(used) - bad.sum() < 3:
            break
        rejected += [used[k] for k in np.nonzero(bad)[0]]
        used = [used[k] for k in np.nonzero(~bad)[0]]
    return AxxbSolution(
        method,
        X_FC,
        float(np.sqrt(np.mean(dt**2))),
        float(np.sqrt(np.mean(dr**2))),
        tuple(used),
        tuple(sorted(rejected)),
    )


def correct_handeye(
    clouds: Sequence[FilteredCloud],
    X_WF: Sequence[np.ndarray],
    X_WC_refined: Sequence[np.ndarray] | None,
    pairs: Sequence[tuple[int, int]],
    X_FC_nominal: np.ndarray,
    config: HandEyeConfig,
    coarse: HandEyeRefinement | None = None,
    X_FC_start: np.ndarray | None = None,
) -> HandEyeResult:
    """AX = XB with every OpenCV method on the refined poses (when there are any), then the
    joint refinement from X_FC_start (the coarse stage's or an earlier round's answer, which
    the registration started from), else from the configured method's answer (or the nominal
    X_FC when that answer is implausible), each step checked against the sanity limits; then
    the diagnosis.

    Args:
        clouds: the views' filtered clouds, in their camera frames C.
        X_WF: each view's flange pose from the robot's joints (4x4, metres).
        X_WC_refined: each view's camera pose after the pose graph (None without ICP: then
            only the joint refinement on the clouds runs).
        pairs: the overlapping view pairs (indices into `clouds`) the refinement matches.
        X_FC_nominal: the hand-eye transform the scan started from.
        config: solver, refinement, sanity limits and convergence limits.
        coarse: the coarse stage's fit, reported with the result.
        X_FC_start: where the registration started from (None: the nominal X_FC).

    Returns:
        The X_FC to use downstream, its change from the nominal one, every AX = XB answer, the
        refinement, which source won, notes on what was not trusted, and the diagnosis (did it
        converge, judged without truth)."""
    X_FC_nominal = np.asarray(X_FC_nominal, float)
    notes: list[str] = []
    axxb: dict[str, AxxbSolution] = {}
    X_start, source = X_FC_nominal, "nominal"
    if coarse is not None and not plausible_correction(coarse.X_FC, X_FC_nominal, config):
        notes.append("the coarse hand-eye fit moved X_FC beyond the sanity limits; not used")
    if X_FC_start is not None and not np.allclose(X_FC_start, X_FC_nominal):
        X_start, source = np.asarray(X_FC_start, float), "coarse"
    if X_WC_refined is not None and len(X_WF) >= 3:
        for name in HAND_EYE_METHODS:
            axxb[name] = solve_axxb(X_WF, X_WC_refined, name, config)
        chosen = axxb[config.axxb_method]
        if source == "coarse":
            pass  # the coarse fit saw every overlap; AX = XB stays a check on it
        elif plausible_correction(chosen.X_FC, X_FC_nominal, config):
            X_start, source = chosen.X_FC, f"axxb:{config.axxb_method}"
        else:
            notes.append(
                f"AX = XB ({config.axxb_method}) moved X_FC beyond the sanity limits; "
                "the refinement starts from the nominal X_FC"
            )
    refinement = None
    X_FC = X_start
    if config.refine and pairs:
        # Open3D's ICP sums in no fixed order: AX = XB on its poses differs between runs of
        # the same scan in the last bits, and the refinement (which stops within a tolerance)
        # would carry that into X_FC and on to the Poisson octree. From a start snapped to a
        # nanometre/nanoradian grid a second run gives the very same model.
        X_start = snapped(X_start, X_FC_nominal)
        refinement = refine_on_clouds(clouds, X_WF, pairs, X_start, config.fine_fit)
        if plausible_correction(refinement.X_FC, X_FC_nominal, config):
            X_FC, source = refinement.X_FC, "refined"
        else:
            notes.append(
                "the joint refinement moved X_FC beyond the sanity limits; not used "
                "(the views may lack the rotation diversity that makes X_FC observable)"
            )
    elif config.refine:
        notes.append("no overlapping view pairs: hand-eye refinement skipped")
    diagnosis = diagnose(
        X_FC,
        refinement,
        axxb[config.axxb_method].X_FC if config.axxb_method in axxb else None,
        None if source == "nominal" else X_start,
        config.convergence,
    )
    dt, dr = pose_difference(X_FC_nominal, X_FC)
    return HandEyeResult(
        X_FC_nominal=X_FC_nominal,
        X_FC=X_FC,
        change_translation_m=dt,
        change_rotation_rad=dr,
        axxb=axxb,
        refinement=refinement,
        source=source,
        notes=tuple(notes),
        coarse=coarse,
        diagnosis=diagnosis,
    )


def plausible_correction(X_FC: np.ndarray, X_FC_nominal: np.ndarray, config: HandEyeConfig) -> bool:
    """Finite and within the sanity limits of the nominal X_FC."""
    if not np.all(np.isfinite(X_FC)):
        return False
    dt, dr = pose_difference(X_FC_nominal, X_FC)
    return dt <= config.max_correction_m and dr <= config.max_correction_rad

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
from scipy.spatial import cKDTree

from reconstruction.calibration.hand_eye import HAND_EYE_METHODS, HandEyeMethodError, solve_hand_eye
from reconstruction.checks import require_choice, require_count, require_positive
from reconstruction.errors import ScannerError
from reconstruction.filtering import FilteredCloud, o3d_cloud
from reconstruction.robust_loss import check_loss, irls_weights
from reconstruction.transforms import (
    invert,
    mean_pose,
    pose_difference,
    rotate_vectors,
    transform_points,
    twist_to_pose,
)


@dataclass(frozen=True)
class RefineLevel:
    """One stage of the joint refinement: correspondence gate and iteration cap."""

    max_correspondence_m: float
    max_iterations: int

    def __post_init__(self) -> None:
        require_positive("handeye.refine_levels", self, ("max_correspondence_m",))
        require_count("handeye.refine_levels", self, ("max_iterations",))


def _default_refine_levels() -> tuple[RefineLevel, ...]:
    # 15 mm covers a 3 mm / 1 deg hand-eye error (up to ~11 mm between views); then tighten to
    # a few times the stereo noise so that wrong matches at the rims drop out.
    return (RefineLevel(0.015, 6), RefineLevel(0.005, 6), RefineLevel(0.002, 20))


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
    # Sanity limits: a correction larger than this is not trusted (the mount cannot be that
    # far off; the scan probably lacks the rotations that make X_FC observable).
    max_correction_m: float = 0.02
    max_correction_rad: float = math.radians(5.0)
    seed: int = 0

    def __post_init__(self) -> None:
        require_choice("handeye", "axxb_method", self.axxb_method, HAND_EYE_METHODS)
        check_loss(self.refine_loss, "handeye.refine_loss")
        if not self.refine_levels:
            raise ScannerError("handeye.refine_levels: at least one level is needed")
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
            ),
        )
        require_count("handeye", self, ("refine_max_points_per_view",), minimum=10)
        require_count("handeye", self, ("axxb_max_rejection_rounds",), minimum=0)


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


@dataclass(frozen=True, eq=False)
class HandEyeRefinement:
    """The joint refinement: X_FC, the RMS point-to-plane residual of the inlier matches
    before/after, the number of matches, iterations, and how well the scan pins X_FC down.

    `formal_std`: standard deviations of the 6 parameters (rotation rad about x, y, z of C,
    then translation m) from the Gauss-Newton normal matrix and the residual; it assumes
    independent matches, so it understates the real spread.
    `weakest_mode` / `weakest_sensitivity`: the direction of X_FC change the clouds notice
    least (rotation components scaled by the working distance, so all six are lengths at the
    object; unit vector) and the RMS point-to-plane change it causes per unit of motion at the
    object (dimensionless, 1 = fully felt). With every view aimed at the scan centre the weakest
    mode is mostly a roll of each view about its optical axis, i.e. a turn about the object's
    centre, which a round object hardly shows (synthetic scans: ~0.01 on the pebble, ~0.02 on
    the bracket). Per-view pose errors (joint offsets) leak into X_FC along it, while the fused
    surface barely changes."""

    X_FC: np.ndarray
    X_FC_start: np.ndarray
    rms_before_m: float
    rms_after_m: float
    n_matches: int
    iterations: int
    formal_std: np.ndarray
    converged: bool
    weakest_mode: np.ndarray
    weakest_sensitivity: float


@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """What the correction decided: X_FC used downstream, its change from the nominal one,
    every AX = XB solver's answer, the refinement (if run), and notes on what was not trusted."""

    X_FC_nominal: np.ndarray
    X_FC: np.ndarray
    change_translation_m: float
    change_rotation_rad: float
    axxb: dict[str, AxxbSolution]
    refinement: HandEyeRefinement | None
    source: str  # "nominal", "axxb:<method>" or "refined"
    notes: tuple[str, ...]


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


@dataclass(frozen=True, eq=False)
class _RefineView:
    source_C: np.ndarray  # thinned points
    target_C: np.ndarray
    normals_C: np.ndarray
    tree: cKDTree


def _prepare(cloud: FilteredCloud, config: HandEyeConfig, rng: np.random.Generator) -> _RefineView:
    pc = o3d_cloud(cloud.points_C, normals=cloud.normals_C)
    target = pc.voxel_down_sample(config.refine_target_voxel_size_m)
    normals = np.asarray(target.normals)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    source = np.asarray(pc.voxel_down_sample(config.refine_voxel_size_m).points)
    if len(source) > config.refine_max_points_per_view:
        pick = rng.choice(len(source), config.refine_max_points_per_view, replace=False)
        source = source[np.sort(pick)]
    target_C = np.asarray(target.points).copy()
    return _RefineView(source, target_C, normals, cKDTree(target_C))


def _matches(
    views: Sequence[_RefineView],
    X_WF: Sequence[np.ndarray],
    sources_of: dict[int, list[int]],
    X_FC: np.ndarray,
    gate_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals n_W . (p_W - q_W) of every source point with a target point within the gate,
    and their Jacobians (n, 6) w.r.t. X_FC <- X_FC @ twist(w, v). All sources of one target
    are queried together (one KD-tree query per target view)."""
    residuals, jacobians = [], []
    X_WC = [X @ X_FC for X in X_WF]
    for t, sources in sources_of.items():
        vt = views[t]
        X_CtW = invert(X_WC[t])
        p_Ct = np.vstack([transform_points(X_CtW @ X_WC[s], views[s].source_C) for s in sources])
        p_Cs = np.vstack([views[s].source_C for s in sources])
        R_WCs = np.vstack(
            [np.broadcast_to(X_WC[s][:3, :3], (len(views[s].source_C), 3, 3)) for s in sources]
        )
        d, k = vt.tree.query(p_Ct, distance_upper_bound=gate_m)
        ok = np.isfinite(d)
        if not ok.any():
            continue
        p_Cs, p_Ct, R_WCs = p_Cs[ok], p_Ct[ok], R_WCs[ok]
        q_Ct, n_Ct = vt.target_C[k[ok]], vt.normals_C[k[ok]]
        # Both points in C_t: n . (p - q) is the same number in W, and cheaper here.
        r = np.einsum("ij,ij->i", n_Ct, p_Ct - q_Ct)
        # d p_W / d(w, v) = R_WC [-[p_C]x, I] for p_W = X_WF @ X_FC @ twist(w, v) @ p_C; the
        # row n_W^T R_WC is (n_W^T R_WCs) for the source and n_Ct^T for the target.
        n_W = rotate_vectors(X_WC[t], n_Ct)
        nR_s = np.einsum("ij,ijk->ik", n_W, R_WCs)
        J_rot = np.cross(p_Cs, nR_s) - np.cross(q_Ct, n_Ct)
        residuals.append(r)
        jacobians.append(np.hstack([J_rot, nR_s - n_Ct]))
    if not residuals:
        return np.zeros(0), np.zeros((0, 6))
    return np.concatenate(residuals), np.vstack(jacobians)


def refine_on_clouds(
    clouds: Sequence[FilteredCloud],
    X_WF: Sequence[np.ndarray],
    pairs: Sequence[tuple[int, int]],
    X_FC_start: np.ndarray,
    config: HandEyeConfig,
) -> HandEyeRefinement:
    """Gauss-Newton with a robust loss (IRLS) over the one X_FC, point-to-plane between every
    overlapping pair in both directions, correspondences re-found at every iteration."""
    rng = np.random.default_rng(config.seed)
    views = [_prepare(c, config, rng) for c in clouds]
    sources_of: dict[int, list[int]] = {}
    for s, t in sorted(set(pairs) | {(t, s) for s, t in pairs}):
        sources_of.setdefault(t, []).append(s)
    X_FC = np.asarray(X_FC_start, float).copy()
    rms_before = None
    iterations = 0
    converged = False
    H = np.eye(6)
    r = np.zeros(0)
    w = np.zeros(0)
    for level in config.refine_levels:
        converged = False
        for _ in range(level.max_iterations):
            r, J = _matches(views, X_WF, sources_of, X_FC, level.max_correspondence_m)
            if len(r) < 6:
                raise ScannerError(
                    "hand-eye refinement: the views do not overlap (fewer than 6 matches)"
                )
            if rms_before is None:
                rms_before = float(np.sqrt(np.mean(r**2)))
            w = irls_weights(r, config.refine_loss, config.refine_loss_scale_m)
            H = J.T @ (w[:, None] * J)
            g = J.T @ (w * r)
            delta = -np.linalg.solve(H + 1e-12 * np.trace(H) * np.eye(6), g)
            X_FC = X_FC @ twist_to_pose(delta)
            iterations += 1
            if (
                np.linalg.norm(delta[:3]) < config.refine_tolerance_rad
                and np.linalg.norm(delta[3:]) < config.refine_tolerance_m
            ):
                converged = True
                break
    r, J = _matches(views, X_WF, sources_of, X_FC, config.refine_levels[-1].max_correspondence_m)
    w = irls_weights(r, config.refine_loss, config.refine_loss_scale_m)
    H = J.T @ (w[:, None] * J)
    # Formal covariance sigma^2 H^-1; matches are correlated (neighbouring points share errors)
    # so this understates the true spread, but it shows which directions the scan constrains.
    sigma2 = float(np.sum(w * r**2) / max(len(r) - 6, 1))
    formal_std = np.sqrt(np.clip(np.diag(np.linalg.pinv(H)) * sigma2, 0, None))
    distance_m = float(np.mean([np.median(v.source_C[:, 2]) for v in views]))
    scale = np.array([distance_m] * 3 + [1.0] * 3)
    eigval, eigvec = np.linalg.eigh(H / scale[:, None] / scale[None, :] / max(float(w.sum()), 1.0))
    return HandEyeRefinement(
        X_FC,
        np.asarray(X_FC_start, float),
        float(rms_before),
        float(np.sqrt(np.mean(r**2))) if len(r) else math.nan,
        len(r),
        iterations,
        formal_std,
        converged,
        eigvec[:, 0] * np.sign(eigvec[np.argmax(np.abs(eigvec[:, 0])), 0]),
        float(np.sqrt(max(eigval[0], 0.0))),
    )


def correct_handeye(
    clouds: Sequence[FilteredCloud],
    X_WF: Sequence[np.ndarray],
    X_WC_refined: Sequence[np.ndarray] | None,
    pairs: Sequence[tuple[int, int]],
    X_FC_nominal: np.ndarray,
    config: HandEyeConfig,
) -> HandEyeResult:
    """AX = XB with every OpenCV method on the refined poses (when there are any), then the
    joint refinement from the configured method's answer (or the nominal X_FC when that answer
    is implausible), each step checked against the sanity limits."""
    X_FC_nominal = np.asarray(X_FC_nominal, float)
    notes: list[str] = []
    axxb: dict[str, AxxbSolution] = {}
    X_start, source = X_FC_nominal, "nominal"
    if X_WC_refined is not None and len(X_WF) >= 3:
        for name in HAND_EYE_METHODS:
            axxb[name] = solve_axxb(X_WF, X_WC_refined, name, config)
        chosen = axxb[config.axxb_method]
        if _plausible(chosen.X_FC, X_FC_nominal, config):
            X_start, source = chosen.X_FC, f"axxb:{config.axxb_method}"
        else:
            notes.append(
                f"AX = XB ({config.axxb_method}) moved X_FC beyond the sanity limits; "
                "the refinement starts from the nominal X_FC"
            )
    refinement = None
    X_FC = X_start
    if config.refine and pairs:
        refinement = refine_on_clouds(clouds, X_WF, pairs, X_start, config)
        if _plausible(refinement.X_FC, X_FC_nominal, config):
            X_FC, source = refinement.X_FC, "refined"
        else:
            notes.append(
                "the joint refinement moved X_FC beyond the sanity limits; not used "
                "(the views may lack the rotation diversity that makes X_FC observable)"
            )
    elif config.refine:
        notes.append("no overlapping view pairs: hand-eye refinement skipped")
    dt, dr = pose_difference(X_FC_nominal, X_FC)
    return HandEyeResult(X_FC_nominal, X_FC, dt, dr, axxb, refinement, source, tuple(notes))


def _plausible(X_FC: np.ndarray, X_FC_nominal: np.ndarray, config: HandEyeConfig) -> bool:
    if not np.all(np.isfinite(X_FC)):
        return False
    dt, dr = pose_difference(X_FC_nominal, X_FC)
    return dt <= config.max_correction_m and dr <= config.max_correction_rad

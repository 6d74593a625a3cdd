"""The joint refinement of the one shared hand-eye transform X_FC directly on the clouds:
Gauss-Newton with a robust loss over point-to-plane matches between every overlapping pair of
views, the correspondences re-found at every iteration, coarse to fine (`CloudFit.levels`).

With X_WC_i = X_WF_i @ X_FC, overlapping views agree only for the right X_FC (each view turns
an X_FC error into a different shift in W); the 6 parameters have no gauge freedom and no
anchor view.
"""

from __future__ import annotations

import math
import threading
import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.common.checks import require_count, require_positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.kdtree import query_workers
from reconstruction.common.robust_loss import check_loss, irls_weights
from reconstruction.common.transforms import invert, rotate_vectors, transform_points, twist_to_pose
from reconstruction.registration.filtering import FilteredCloud, o3d_cloud


def check_fit_settings(loss: str, loss_field: str, levels: tuple, levels_field: str) -> None:
    """What every joint X_FC fit needs (the coarse and the fine configuration name these
    fields differently): a known robust loss and at least one level."""
    check_loss(loss, loss_field)
    if not levels:
        raise ScannerError(f"{levels_field}: at least one level is needed")


@dataclass(frozen=True)
class RefineLevel:
    """One stage of the joint refinement: correspondence gate, iteration cap, and at most how
    many of each view's (thinned, capped) source points it matches (0: all of them)."""

    max_correspondence_m: float
    max_iterations: int
    points_per_view: int = 0

    def __post_init__(self) -> None:
        require_positive("handeye.refine_levels", self, ("max_correspondence_m",))
        require_count("handeye.refine_levels", self, ("max_iterations",))
        require_count("handeye.refine_levels", self, ("points_per_view",), minimum=0)


@dataclass(frozen=True)
class CloudFit:
    """How one joint refinement samples and matches the clouds: sources thinned to
    `voxel_size_m` and capped per view (6 unknowns need far fewer matches than ICP does),
    targets at `target_voxel_size_m` for the tangent planes, the robust loss and its scale,
    the coarse-to-fine gates, and the step size that ends a level."""

    levels: tuple[RefineLevel, ...]
    voxel_size_m: float
    target_voxel_size_m: float
    max_points_per_view: int
    loss: str
    loss_scale_m: float
    tolerance_m: float
    tolerance_rad: float
    seed: int = 0

    def __post_init__(self) -> None:
        check_fit_settings(self.loss, "handeye loss", self.levels, "handeye levels")


@dataclass(frozen=True, eq=False)
class HandEyeRefinement:
    """The joint refinement: X_FC, the RMS point-to-plane residual of the inlier matches
    before/after, the number of matches, iterations, and how well the scan pins X_FC down.

    `formal_std`: standard deviations of the 6 parameters (rotation rad about x, y, z of C,
    then translation m) from the Gauss-Newton normal matrix and the residual; it assumes
    independent matches, so it understates the real spread.
    `jackknife_std`: the same 6 standard deviations from the views themselves, by the
    delete-one-view jackknife (`view_jackknife_covariance`): what the fit states as its accuracy.
    `sigma_translation_m` / `sigma_rotation_rad`: that accuracy as the expected (RMS) size of
    the error of the camera's origin and of its orientation, the figures a true error is judged
    against (the square root of the trace of the translation / rotation block of the larger of
    the two covariances; NaN when the views cannot say, e.g. fewer than 3 of them).
    `last_step_m` / `last_step_rad`: the fit's last Gauss-Newton step, what it was still moving
    when it stopped.
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
    match_fraction: float  # source points with a match within the last gate
    weakest_mode: np.ndarray
    weakest_sensitivity: float
    jackknife_std: np.ndarray
    sigma_translation_m: float
    sigma_rotation_rad: float
    last_step_m: float
    last_step_rad: float


@dataclass(frozen=True, eq=False)
class _RefineView:
    source_C: np.ndarray  # thinned points
    target_C: np.ndarray
    normals_C: np.ndarray
    tree: cKDTree


def _prepare(cloud: FilteredCloud, settings: CloudFit) -> _RefineView:
    """The view's sources (thinned, at most `max_points_per_view`, drawn with a generator of
    its own: the same sample whichever views come before it) and its targets with normals."""
    pc = o3d_cloud(cloud.points_C, normals=cloud.normals_C)
    target = pc.voxel_down_sample(settings.target_voxel_size_m)
    normals = np.asarray(target.normals)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    source = np.asarray(pc.voxel_down_sample(settings.voxel_size_m).points)
    if len(source) > settings.max_points_per_view:
        rng = np.random.default_rng((settings.seed, cloud.index))
        pick = rng.choice(len(source), settings.max_points_per_view, replace=False)
        source = source[np.sort(pick)]
    target_C = np.asarray(target.points).copy()
    return _RefineView(source, target_C, normals, cKDTree(target_C))


# Each cloud's prepared view, per sampling (the same cloud object gives the same view). The
# scan's view stream prepares every view as it arrives (`prepare_view`), so that the fit after
# the last picture finds them made (about 1 s of a 48-view scan's wait), and the rounds of
# one correction prepare each view once. Weak keys: a view goes with its cloud.
_prepared: weakref.WeakKeyDictionary[FilteredCloud, dict[tuple, _RefineView]] = (
    weakref.WeakKeyDictionary()
)
_prepared_lock = threading.Lock()


def _sampling(settings: CloudFit) -> tuple:
    return (
        settings.voxel_size_m,
        settings.target_voxel_size_m,
        settings.max_points_per_view,
        settings.seed,
    )


def prepare_view(cloud: FilteredCloud, settings: CloudFit) -> _RefineView:
    """`cloud` sampled for a joint fit with `settings`, made once per cloud and sampling."""
    key = _sampling(settings)
    with _prepared_lock:
        made = _prepared.get(cloud, {}).get(key)
    if made is None:
        made = _prepare(cloud, settings)
        with _prepared_lock:
            _prepared.setdefault(cloud, {})[key] = made
    return made


@dataclass(frozen=True, eq=False)
class _Matches:
    """Point-to-plane residuals (n,), their Jacobians (n, 6) w.r.t. X_FC <- X_FC @ twist(w, v),
    and the list positions of each match's source and target view (n,)."""

    r: np.ndarray
    J: np.ndarray
    source: np.ndarray
    target: np.ndarray


def _level_sources(views: Sequence[_RefineView], points_per_view: int) -> list[np.ndarray]:
    """Each view's source points for one level: every k-th, so that at most `points_per_view`
    remain (all of them for 0)."""
    out = []
    for v in views:
        n = len(v.source_C)
        out.append(
            v.source_C[:: -(-n // points_per_view)] if 0 < points_per_view < n else v.source_C
        )
    return out


def _matches(
    views: Sequence[_RefineView],
    sources_C: Sequence[np.ndarray],
    X_WF: Sequence[np.ndarray],
    sources_of: dict[int, list[int]],
    X_FC: np.ndarray,
    gate_m: float,
) -> _Matches:
    """Residuals n_W . (p_W - q_W) of every source point (`sources_C`, per view) with a target
    point within the gate, and their Jacobians. All sources of one target are queried together
    (one KD-tree query per target view)."""
    residuals, jacobians, source_of, target_of = [], [], [], []
    X_WC = [X @ X_FC for X in X_WF]
    for t, sources in sources_of.items():
        vt = views[t]
        X_CtW = invert(X_WC[t])
        p_Ct = np.vstack([transform_points(X_CtW @ X_WC[s], sources_C[s]) for s in sources])
        d, k = vt.tree.query(p_Ct, distance_upper_bound=gate_m, workers=query_workers(len(p_Ct)))
        ok = np.isfinite(d)
        if not ok.any():
            continue
        # The matches of each source view, a block each (the sources were stacked in order).
        ends = np.cumsum([len(sources_C[s]) for s in sources])
        bounds = np.searchsorted(np.flatnonzero(ok), np.concatenate([[0], ends]))
        p_Cs = np.vstack([sources_C[s] for s in sources])[ok]
        p_Ct = p_Ct[ok]
        q_Ct, n_Ct = vt.target_C[k[ok]], vt.normals_C[k[ok]]
        # Both points in C_t: n . (p - q) is the same number in W, and cheaper here.
        r = np.einsum("ij,ij->i", n_Ct, p_Ct - q_Ct)
        # d p_W / d(w, v) = R_WC [-[p_C]x, I] for p_W = X_WF @ X_FC @ twist(w, v) @ p_C; the
        # row n_W^T R_WC is (n_W^T R_WCs) for the source and n_Ct^T for the target.
        n_W = rotate_vectors(X_WC[t], n_Ct)
        nR_s = np.empty_like(n_W)
        for s, a, b in zip(sources, bounds[:-1], bounds[1:]):
            nR_s[a:b] = n_W[a:b] @ X_WC[s][:3, :3]
        J_rot = np.cross(p_Cs, nR_s) - np.cross(q_Ct, n_Ct)
        residuals.append(r)
        jacobians.append(np.hstack([J_rot, nR_s - n_Ct]))
        source_of.append(np.repeat(sources, np.diff(bounds)))
        target_of.append(np.full(len(r), t))
    if not residuals:
        empty = np.zeros(0, dtype=int)
        return _Matches(np.zeros(0), np.zeros((0, 6)), empty, empty)
    return _Matches(
        np.concatenate(residuals),
        np.vstack(jacobians),
        np.concatenate(source_of),
        np.concatenate(target_of),
    )


def refine_on_clouds(
    clouds: Sequence[FilteredCloud],
    X_WF: Sequence[np.ndarray],
    pairs: Sequence[tuple[int, int]],
    X_FC_start: np.ndarray,
    settings: CloudFit,
) -> HandEyeRefinement:
    """Gauss-Newton with a robust loss (IRLS) over the one X_FC, point-to-plane between every
    overlapping pair in both directions, correspondences re-found at every iteration."""
    views = [prepare_view(c, settings) for c in clouds]
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
    delta = np.zeros(6)
    every = [v.source_C for v in views]
    for level in settings.levels:
        converged = False
        sources_C = _level_sources(views, level.points_per_view)
        for _ in range(level.max_iterations):
            m = _matches(views, sources_C, X_WF, sources_of, X_FC, level.max_correspondence_m)
            r, J = m.r, m.J
            if len(r) < 6:
                raise ScannerError(
                    "hand-eye refinement: the views do not overlap (fewer than 6 matches)"
                )
            if rms_before is None:
                rms_before = float(np.sqrt(np.mean(r**2)))
            w = irls_weights(r, settings.loss, settings.loss_scale_m)
            H = J.T @ (w[:, None] * J)
            g = J.T @ (w * r)
            delta = -np.linalg.solve(H + 1e-12 * np.trace(H) * np.eye(6), g)
            X_FC = X_FC @ twist_to_pose(delta)
            iterations += 1
            if (
                np.linalg.norm(delta[:3]) < settings.tolerance_rad
                and np.linalg.norm(delta[3:]) < settings.tolerance_m
            ):
                converged = True
                break
    last_step = (float(np.linalg.norm(delta[3:])), float(np.linalg.norm(delta[:3])))
    m = _matches(views, every, X_WF, sources_of, X_FC, settings.levels[-1].max_correspondence_m)
    r, J = m.r, m.J
    queried = sum(len(views[s].source_C) for sources in sources_of.values() for s in sources)
    w = irls_weights(r, settings.loss, settings.loss_scale_m)
    H = J.T @ (w[:, None] * J)
    # Formal covariance sigma^2 H^-1; matches are correlated (neighbouring points share errors)
    # so this understates the true spread, but it shows which directions the scan constrains.
    sigma2 = float(np.sum(w * r**2) / max(len(r) - 6, 1))
    formal_cov = np.linalg.pinv(H) * sigma2
    formal_std = np.sqrt(np.clip(np.diag(formal_cov), 0, None))
    jackknife_cov = view_jackknife_covariance(m, w, len(views))
    stated = np.maximum(np.diag(jackknife_cov), np.diag(formal_cov))
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
        len(r) / max(queried, 1),
        eigvec[:, 0] * np.sign(eigvec[np.argmax(np.abs(eigvec[:, 0])), 0]),
        float(np.sqrt(max(eigval[0], 0.0))),
        np.sqrt(np.clip(np.diag(jackknife_cov), 0, None)),
        float(np.sqrt(np.sum(stated[3:]))),
        float(np.sqrt(np.sum(stated[:3]))),
        *last_step,
    )


def view_jackknife_covariance(m: _Matches, w: np.ndarray, n_views: int) -> np.ndarray:
    """Covariance (6, 6) of the fitted X_FC parameters (rotation, translation) by the
    delete-one-view jackknife, linearised at the fit: the Gauss-Newton step of the fit without
    view v's matches (as source or target), from the answer with all of them, for every view;
    then (n - 1) / n times the scatter of those steps (Efron's jackknife variance). NaN when
    fewer than 3 views have matches or the fit without one of them is undetermined.

    Why the views and not the matches. The formal covariance sigma^2 H^-1 counts every match as
    an independent measurement, but a view's matches share that view's errors: its flange pose
    error (the robot's joint offsets, a few hundredths of a millimetre at the flange), its
    stereo's slant. Those, not the depth noise of single points, leak into X_FC, and only a
    measure of how much X_FC depends on each view sees them (synthetic 10-view scans with
    0.05 mm / 0.005 deg flange errors: formal 0.03 mm, jackknife 0.13-0.49 mm, true error
    0.09-0.27 mm). Splitting the views in two halves would give one difference per parameter,
    a variance from a single sample; the jackknife gives one step per view. Refitting without
    each view would cost 20-odd fits; one Gauss-Newton step from the answer costs a 6x6 solve,
    and a view moves X_FC by far less than the finest gate, where the step is the refit. What
    it cannot see: an error every view shares in the flange or camera frame (a joint-6 encoder
    offset, a stereo depth bias along the optical axis) moves X_FC without disagreement
    between the views."""
    r, J = m.r, m.J
    nan = np.full((6, 6), np.nan)
    H = J.T @ (w[:, None] * J)
    g = J.T @ (w * r)
    steps = []
    for v in range(n_views):
        mine = (m.source == v) | (m.target == v)
        if not mine.any():
            continue
        H_rest = H - J[mine].T @ (w[mine, None] * J[mine])
        g_rest = g - J[mine].T @ (w[mine] * r[mine])
        if np.linalg.cond(H_rest) > 1e12:
            return nan
        steps.append(-np.linalg.solve(H_rest, g_rest))
    n = len(steps)
    if n < 3:
        return nan
    d = np.array(steps) - np.mean(steps, axis=0)
    return (n - 1) / n * d.T @ d

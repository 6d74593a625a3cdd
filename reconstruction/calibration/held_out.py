"""How far to trust a hand-eye calibration: views held out and views resampled. Pure numeric.

The refinement's covariance says how well the images pin X_FC down if the robot's reported
poses are right up to the prior it was given. On a real arm they are not: its own pose errors
(about a millimetre on a 6-axis arm) dominate, and a covariance that does not see them is too
small by several times. Two figures do see them:

- held-out prediction (k-fold): fit on the other views, predict the board corners of each
  held-out view from its reported pose alone, compare with the detections. It measures what a
  scan relies on (a pose nobody corrected) and ranks solvers on data they did not fit;
- the bootstrap: refit on views drawn with replacement; the spread of X_FC over the refits is
  its uncertainty, robot errors included as far as they differ from view to view.

Both refit many times. The refits are Gauss-Newton steps of the refinement's own problem,
linearised at its solution (`refine.Linearization`) with each view's rows reweighted (0: held
out; k: drawn k times): exact to first order, as a nonlinear refit from the solution converges
in one step to within a fraction of the spread it measures (tested), and a thousand times
cheaper, so every calibration reports them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.hand_eye import solve_every_method
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.refine import (
    Linearization,
    reprojection_residuals,
    sensor_points,
)
from reconstruction.common.transforms import invert, mean_pose, transform_points, twist_to_pose
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera

# Fewer views than this: leave one out rather than k folds of one view or less each.
MIN_VIEWS_FOR_K_FOLD = 6


@dataclass(frozen=True)
class Folds:
    """Which views each fold holds out (indices into the views used), and how they were made."""

    groups: tuple[tuple[int, ...], ...]
    leave_one_out: bool

    def words(self) -> str:
        if self.leave_one_out:
            return f"leave-one-out over {len(self.groups)} views"
        return f"{len(self.groups)}-fold"


def make_folds(n_views: int, k: int = 5, seed: int = 0) -> Folds:
    """k folds of a seeded permutation; leave-one-out below `MIN_VIEWS_FOR_K_FOLD` views (a
    fold must leave enough views to fit) or when k >= n_views."""
    if n_views < MIN_VIEWS_FOR_K_FOLD or k >= n_views:
        return Folds(tuple((i,) for i in range(n_views)), True)
    order = np.random.default_rng(seed).permutation(n_views)
    return Folds(tuple(tuple(sorted(int(i) for i in g)) for g in np.array_split(order, k)), False)


@dataclass(frozen=True, eq=False)
class Solution:
    """What predicts a view: X_FC, X_WB and the arm's error parameters (None: the reported
    flange poses are used as they are)."""

    X_FC: np.ndarray
    X_WB: np.ndarray
    robot_params: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class ViewBlocks:
    """The linearised normal equations reduced to the shared parameters (X_FC, X_WB, the
    offsets) and split by view: a view's robot correction appears only in its own rows, so it
    is eliminated per view (Schur complement) and a refit on view weights w is
    (sum_v w_v A_v) step = -(sum_v w_v b_v): a sum and one small solve."""

    A: np.ndarray  # (V, n, n), n = 12 + offsets
    b: np.ndarray  # (V, n)
    n_offsets: int


def view_blocks(lin: Linearization) -> ViewBlocks:
    J = lin.J.toarray()
    nb = 12 + lin.n_offsets
    A = np.zeros((lin.n_poses, nb, nb))
    b = np.zeros((lin.n_poses, nb))
    for v in range(lin.n_poses):
        rows = lin.row_pose == v
        Jw = J[rows] * lin.irls[rows, None]
        Jb = J[rows, :nb]
        A[v] = Jw[:, :nb].T @ Jb
        b[v] = Jw[:, :nb].T @ lin.f[rows]
        if lin.corrections:
            c = slice(nb + 6 * v, nb + 6 * v + 6)
            Hcc = Jw[:, c].T @ J[rows, c]
            Hbc = Jw[:, :nb].T @ J[rows, c]
            A[v] -= Hbc @ np.linalg.solve(Hcc, Hbc.T)
            b[v] -= Hbc @ np.linalg.solve(Hcc, Jw[:, c].T @ lin.f[rows])
    return ViewBlocks(A, b, lin.n_offsets)


def refit(
    blocks: ViewBlocks,
    start: Solution,
    estimated: Sequence[int],
    view_weights: np.ndarray,
) -> tuple[Solution, np.ndarray]:
    """The solution of the linearised problem with each view's rows weighted by
    `view_weights` (one Gauss-Newton step from `start`), and the step's X_FC twist (in C)."""
    w = np.asarray(view_weights, float)
    step = -np.linalg.solve(np.tensordot(w, blocks.A, axes=1), w @ blocks.b)
    params = None
    if start.robot_params is not None:
        params = start.robot_params.copy()
        params[list(estimated)] += step[12 : 12 + blocks.n_offsets]
    return (
        Solution(
            start.X_FC @ twist_to_pose(step[:6]),
            start.X_WB @ twist_to_pose(step[6:12]),
            params,
        ),
        step[:6],
    )


def bootstrap_twists(
    lin: Linearization,
    start: Solution,
    estimated: Sequence[int],
    samples: int = 200,
    seed: int = 0,
) -> np.ndarray:
    """(samples, 6) X_FC twists (rotation rad, translation m, in C) of refits on views drawn
    with replacement."""
    rng = np.random.default_rng(seed)
    n = lin.n_poses
    blocks = view_blocks(lin)
    out = np.empty((samples, 6))
    for b in range(samples):
        counts = rng.multinomial(n, np.full(n, 1.0 / n)).astype(float)
        out[b] = refit(blocks, start, estimated, counts)[1]
    return out


@dataclass(frozen=True)
class HeldOutError:
    """Prediction error of held-out views: RMS over their board corners in pixels and in
    millimetres on the board (each pixel error times the corner's depth over the focal length),
    and the RMS of each view (px, in the order of the views used)."""

    rms_px: float
    rms_m: float
    per_view_px: tuple[float, ...]

    def as_dict(self) -> dict:
        return {"rms_px": self.rms_px, "rms_mm": 1e3 * self.rms_m}


def view_errors(
    board: BoardSpec,
    observation: PoseObservation,
    cameras: StereoCamera | PinholeCamera,
    X_WF: np.ndarray,
    solution: Solution,
) -> tuple[np.ndarray, np.ndarray]:
    """Per board point of one view (every camera): the prediction error in px and in metres
    on the board, with the flange at X_WF (its reported or kinematic pose, uncorrected)."""
    sensors = sensor_points(board, [observation], cameras)
    residuals = reprojection_residuals(sensors, X_WF[None], solution.X_FC, solution.X_WB)
    X_CB = invert(X_WF @ solution.X_FC) @ solution.X_WB
    px, metres = [], []
    for s, r in zip(sensors, residuals):
        depth = transform_points(s.X_SC @ X_CB, s.p_B)[:, 2]
        focal = 0.5 * (s.camera.K[0, 0] + s.camera.K[1, 1])
        e = np.linalg.norm(r, axis=1)
        px.append(e)
        metres.append(e * depth / focal)
    return np.concatenate(px), np.concatenate(metres)


def _summarise(per_view: list[tuple[np.ndarray, np.ndarray]]) -> HeldOutError:
    px = np.concatenate([p for p, _ in per_view])
    mm = np.concatenate([m for _, m in per_view])
    return HeldOutError(
        float(np.sqrt(np.mean(px**2))),
        float(np.sqrt(np.mean(mm**2))),
        tuple(float(np.sqrt(np.mean(p**2))) for p, _ in per_view),
    )


def held_out_refined(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    lin: Linearization,
    solution: Solution,
    estimated: Sequence[int],
    folds: Folds,
    flange_pose: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> HeldOutError:
    """The refinement's held-out error: per fold, the linearised refit without the fold's
    views predicts them. With robot parameters a view's flange pose is flange_pose(q, p)."""
    per_view: list = [None] * len(observations)
    blocks = view_blocks(lin)
    for group in folds.groups:
        weights = np.ones(len(observations))
        weights[list(group)] = 0.0
        fit, _ = refit(blocks, solution, estimated, weights)
        for i in group:
            o = observations[i]
            X_WF = o.X_WF
            if fit.robot_params is not None:
                X_WF = flange_pose(np.asarray(o.q_rad), fit.robot_params)
            per_view[i] = view_errors(board, o, cameras, X_WF, fit)
    return _summarise(per_view)


def held_out_closed_form(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    X_CB: Sequence[np.ndarray],
    folds: Folds,
) -> dict[str, HeldOutError]:
    """Each of OpenCV's AX = XB methods refitted per fold (X_WB: the mean board pose its X_FC
    implies on the fold's training views); a method that fails on any fold is left out."""
    per_method: dict[str, list] = {}
    failed: set[str] = set()
    n = len(observations)
    for group in folds.groups:
        train = [i for i in range(n) if i not in group]
        X_WF = [observations[i].X_WF for i in train]
        estimates, failures = solve_every_method(X_WF, [X_CB[i] for i in train])
        failed |= set(failures)
        for name, X_FC in estimates.items():
            X_WB = mean_pose([Xf @ X_FC @ X_CB[i] for Xf, i in zip(X_WF, train)])
            fit = Solution(X_FC, X_WB)
            rows = per_method.setdefault(name, [None] * n)
            for i in group:
                o = observations[i]
                rows[i] = view_errors(board, o, cameras, o.X_WF, fit)
    return {
        name: _summarise(rows)
        for name, rows in per_method.items()
        if name not in failed and all(r is not None for r in rows)
    }

"""Joint refinement of X_FC and the board pose X_WB on every board corner in every camera.

The board is fixed in W, so X_CB_i = (X_WF_i X_FC)^-1 X_WB for every pose i: one X_FC and one
X_WB (plus, optionally, a small correction of each reported robot pose) explain all corners.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative
from scipy.sparse import csr_matrix, lil_matrix

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.robust_loss import irls_weights
from reconstruction.common.transforms import invert, transform_points, twist_to_pose
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera, project_points


@dataclass(frozen=True, eq=False)
class SensorPoints:
    camera: PinholeCamera
    X_SC: np.ndarray  # this sensor's frame S seen from the left camera C
    pose_index: np.ndarray  # (N,) which observation each point belongs to
    p_B: np.ndarray  # (N, 3)
    pixels: np.ndarray  # (N, 2)


def sensor_points(
    board: BoardSpec, observations: Sequence[PoseObservation], cameras: StereoCamera | PinholeCamera
) -> list[SensorPoints]:
    if isinstance(cameras, StereoCamera):
        rigs = [(cameras.left, np.eye(4), "left"), (cameras.right, invert(cameras.X_CR), "right")]
    else:
        rigs = [(cameras, np.eye(4), "left")]
    p_board = board.object_points()
    out = []
    for camera, X_SC, side in rigs:
        idx, p_B, px = [], [], []
        for k, o in enumerate(observations):
            d = getattr(o, side)
            if d is None:
                continue
            idx.append(np.full(len(d), k))
            p_B.append(p_board[d.ids])
            px.append(d.pixels)
        if idx:
            out.append(
                SensorPoints(camera, X_SC, np.concatenate(idx), np.vstack(p_B), np.vstack(px))
            )
    return out


def reprojection_residuals(
    sensors: list[SensorPoints], X_WF: np.ndarray, X_FC: np.ndarray, X_WB: np.ndarray
) -> list[np.ndarray]:
    """Per sensor: (N, 2) residual pixels (observed - predicted)."""
    # X_CB_i = (X_WF_i X_FC)^-1 X_WB for every pose at once.
    X_WC = X_WF @ X_FC
    R_CW = np.transpose(X_WC[:, :3, :3], (0, 2, 1))
    p_CW = -np.einsum("kij,kj->ki", R_CW, X_WC[:, :3, 3])
    out = []
    for s in sensors:
        p_W = transform_points(X_WB, s.p_B)
        k = s.pose_index
        p_C = np.einsum("nij,nj->ni", R_CW[k], p_W) + p_CW[k]
        p_S = transform_points(s.X_SC, p_C)
        out.append(s.pixels - project_points(s.camera, p_S))
    return out


def pose_rms(sensors: list[SensorPoints], residuals: list[np.ndarray], n_poses: int) -> np.ndarray:
    sq = np.zeros(n_poses)
    count = np.zeros(n_poses)
    for s, r in zip(sensors, residuals):
        np.add.at(sq, s.pose_index, np.sum(r * r, axis=1))
        np.add.at(count, s.pose_index, 1)
    return np.sqrt(sq / np.maximum(count, 1))


@dataclass(frozen=True, eq=False)
class Refinement:
    """Refined X_FC and X_WB; per-pose rigid-model RMS (px, with the robot poses as reported)
    and the per-pose robot corrections the estimate implies (X_WF_i @ exp(xi_i), xi (V, 6):
    rotation vector rad, translation m, in the flange frame)."""

    X_FC: np.ndarray
    X_WB: np.ndarray
    rms_px: float  # rigid model, all points of all sensors
    pose_rms_px: np.ndarray  # (V,)
    corrections: np.ndarray  # (V, 6)
    corrected_rms_px: float  # with the robot corrections applied: what the images alone leave
    evaluations: int
    # Covariance (6, 6) of X_FC's twist delta: rotation vector (rad) then translation (m), both
    # in the camera frame C (X_FC_true = X_FC @ twist_to_pose(delta)); see `x_fc_covariance`.
    X_FC_covariance: np.ndarray = field(default_factory=lambda: np.full((6, 6), np.nan))
    # The arm's error parameters (robot_errors.ArmModel; None: the reported poses were used)
    # and which of them were estimated.
    robot_params: np.ndarray | None = None
    estimated: tuple[int, ...] = ()
    # Computes the `Linearization` (a Jacobian by finite differences): called only for the
    # refinements that are assessed, not for every round of the outlier test.
    linearize: Callable[[], Linearization] | None = None

    @property
    def linearization(self) -> Linearization | None:
        return None if self.linearize is None else self.linearize()


@dataclass(frozen=True, eq=False)
class Linearization:
    """The refinement's problem linearised at its solution, for cheap refits on other weights
    of the same poses (held-out folds, bootstrap resamples; see `calibration.held_out`).

    Parameters: X_FC's twist (0:6), X_WB's twist (6:12), the estimated robot parameters
    (12:12 + n_offsets), then 6 per pose for the robot corrections when estimated.
    J: raw Jacobian of the residuals (in sigmas) by forward differences; f: the residuals;
    irls: each residual's robust-loss weight at the solution; row_pose: the pose each row
    belongs to (a pixel row or a robot-correction prior row)."""

    J: csr_matrix
    f: np.ndarray
    irls: np.ndarray
    row_pose: np.ndarray
    n_poses: int
    n_offsets: int
    corrections: bool


def _jacobian_sparsity(
    sensors: list[SensorPoints], n_poses: int, with_corrections: bool, n_offsets: int = 0
):
    n_pixels = sum(2 * len(s.pose_index) for s in sensors)
    base = 12 + n_offsets
    n_params = base + (6 * n_poses if with_corrections else 0)
    n_rows = n_pixels + (6 * n_poses if with_corrections else 0)
    J = lil_matrix((n_rows, n_params), dtype=int)
    J[:n_pixels, :base] = 1
    if with_corrections:
        row = 0
        for s in sensors:
            for k in s.pose_index:
                J[row : row + 2, base + 6 * k : base + 6 + 6 * k] = 1
                row += 2
        for k in range(n_poses):
            J[n_pixels + 6 * k : n_pixels + 6 * k + 6, base + 6 * k : base + 6 + 6 * k] = np.eye(
                6, dtype=int
            )
    return J


def _row_pose(sensors: list[SensorPoints], n_poses: int, with_corrections: bool) -> np.ndarray:
    pixel_rows = [np.repeat(s.pose_index, 2) for s in sensors]
    prior_rows = [np.repeat(np.arange(n_poses), 6)] if with_corrections else []
    return np.concatenate(pixel_rows + prior_rows).astype(int)


def refine_on_board(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    X_FC0: np.ndarray,
    X_WB0: np.ndarray,
    settings: CalibrationSettings = CalibrationSettings(),
    joints: np.ndarray | None = None,
    flange_pose: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    estimated: Sequence[int] = (),
    params0: np.ndarray | None = None,
) -> Refinement:
    """Maximum-likelihood X_FC and X_WB: reprojection errors of every board point in every
    camera (sigma pixel_sigma_px) and, when the robot sigmas are positive, a small correction
    of every reported flange pose with its prior (robot_*_sigma). Without the corrections a
    robot's own pose errors (0.02 deg is 0.3 mm at 0.85 m) are absorbed by X_FC, which far
    from the board and with small tilts moves it by centimetres along weakly observed
    directions; with them the images decide what they measure well (lateral position) and the
    robot's accuracy bounds the rest. A robust loss (in sigmas) limits the pull of bad points.

    Poses are parameterised as X0 @ exp(xi): small, well-scaled parameters near the seed.

    With `estimated` (indices into the arm's error parameters p, `robot_errors.ArmModel`; and
    every pose's reported `joints` with the arm's `flange_pose(q, p)`), those parameters (joint
    zero offsets, link lengths) are estimated too: each flange pose is then flange_pose(q, p)
    rather than the reported X_WF, so a systematic robot error is explained once instead of by
    every pose's correction and, through them, by X_FC.
    """
    sensors = sensor_points(board, observations, cameras)
    X_WF = np.array([o.X_WF for o in observations])
    n = len(observations)
    corrections = settings.robot_translation_sigma_m > 0 and settings.robot_rotation_sigma_rad > 0
    estimated = tuple(int(j) for j in estimated)
    m = len(estimated)
    if m or params0 is not None:
        if joints is None or flange_pose is None or params0 is None:
            raise ValueError("robot parameters need every pose's joints and the arm's model")
        joints = np.asarray(joints, float)
        base_params = np.asarray(params0, float).copy()
    else:
        base_params = None

    def params_of(x) -> np.ndarray | None:
        if base_params is None:
            return None
        p = base_params.copy()
        p[list(estimated)] += x[12 : 12 + m]
        return p

    def flange_poses(x) -> np.ndarray:
        if base_params is None:
            return X_WF
        p = params_of(x)
        return np.array([flange_pose(q, p) for q in joints])

    prior_scale = np.r_[
        np.full(3, 1 / max(settings.robot_rotation_sigma_rad, 1e-12)),
        np.full(3, 1 / max(settings.robot_translation_sigma_m, 1e-12)),
    ]

    def unpack(x):
        X_FC = X_FC0 @ twist_to_pose(x[:6])
        X_WB = X_WB0 @ twist_to_pose(x[6:12])
        xi = x[12 + m :].reshape(n, 6) if corrections else np.zeros((n, 6))
        return X_FC, X_WB, xi

    def corrected(X_WF_base, xi):
        if not corrections:
            return X_WF_base
        return np.array([X @ twist_to_pose(d) for X, d in zip(X_WF_base, xi)])

    def fun(x):
        X_FC, X_WB, xi = unpack(x)
        pixels = reprojection_residuals(sensors, corrected(flange_poses(x), xi), X_FC, X_WB)
        parts = [r.ravel() / settings.pixel_sigma_px for r in pixels]
        if corrections:
            parts.append((xi * prior_scale).ravel())
        return np.concatenate(parts)

    sparsity = _jacobian_sparsity(sensors, n, corrections, m)
    result = least_squares(
        fun,
        np.zeros(12 + m + (6 * n if corrections else 0)),
        jac_sparsity=sparsity,
        loss=settings.robust_loss,
        f_scale=settings.robust_scale,
        x_scale="jac",
        method="trf",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=100,
        # The sparse trust-region steps are solved by LSMR; its default tolerances are too
        # loose once the pixel noise is measured small (the problem is badly conditioned along
        # each view's depth): the solve then stalled at the evaluation cap and its answer
        # moved by micrometres with the BLAS thread count. Tight inner tolerances converge in
        # 10-23 evaluations to the same answer every time.
        tr_options={"atol": 1e-12, "btol": 1e-12},
    )
    X_FC, X_WB, xi = unpack(result.x)
    covariance = x_fc_covariance(result.jac, result.fun)
    X_WF_model = flange_poses(result.x)
    residuals = reprojection_residuals(sensors, X_WF_model, X_FC, X_WB)
    after = reprojection_residuals(sensors, corrected(X_WF_model, xi), X_FC, X_WB)

    @functools.cache
    def linearize() -> Linearization:
        # The raw Jacobian at the solution (scipy's result.jac is rescaled by the robust loss).
        J = approx_derivative(fun, result.x, f0=result.fun, sparsity=sparsity)
        return Linearization(
            csr_matrix(J),
            result.fun.copy(),
            irls_weights(result.fun, settings.robust_loss, settings.robust_scale),
            _row_pose(sensors, n, corrections),
            n,
            m,
            corrections,
        )

    return Refinement(
        X_FC,
        X_WB,
        _rms(residuals),
        pose_rms(sensors, residuals, n),
        xi,
        _rms(after),
        int(result.nfev),
        covariance,
        params_of(result.x),
        estimated,
        linearize,
    )


def x_fc_covariance(jacobian, residuals: np.ndarray) -> np.ndarray:
    """Covariance (6, 6) of the first six parameters (X_FC's twist) at a least-squares
    solution: cov = s^2 (J^T J)^-1 with s^2 = |r|^2 / (m - n), the residual variance per degree
    of freedom, so the spread the data show (not only the sigmas they were weighted with) sets
    the scale. The robot-pose corrections and the board pose are in J: their uncertainty widens
    X_FC's (the marginal, not the conditional, covariance). NaN when J^T J is singular.

    `jacobian` is scipy's (with a robust loss its rows are already reweighted: J^T J is the
    Gauss-Newton Hessian of the robust cost), `residuals` the unweighted residual vector.
    """
    J = jacobian.toarray() if hasattr(jacobian, "toarray") else np.asarray(jacobian, float)
    m, n = J.shape
    if m <= n:
        return np.full((6, 6), np.nan)
    s2 = float(residuals @ residuals) / (m - n)
    JTJ = J.T @ J
    try:
        # Only the X_FC block is needed: solve for six columns of the inverse.
        block = np.linalg.solve(JTJ, np.eye(n)[:, :6])[:6]
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.nan)
    return s2 * (block[:, :6] + block[:, :6].T) / 2


def _rms(residuals: list[np.ndarray]) -> float:
    return float(np.sqrt(np.concatenate([np.sum(r * r, axis=1) for r in residuals]).mean()))

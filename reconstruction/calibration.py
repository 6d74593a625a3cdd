"""Camera, stereo and hand-eye (eye-in-hand) calibration from board observations. Pure numeric.

Frames (DESIGN.md): W robot base, F flange, C left optical frame, R right optical frame, B board.
The robot reports X_WF for every pose; PnP gives X_CB (OpenCV's solvePnP returns the board in the
camera); the board is fixed in W, so X_WB = X_WF_i @ X_FC @ X_CB_i for every pose i, and the
hand-eye transform X_FC is what OpenCV's calibrateHandEye returns as "cam2gripper".

Pipeline (`calibrate_hand_eye`):
1. board pose per robot pose by PnP (intrinsics from the stereo/mono calibration or given);
2. refuse too few poses or degenerate motions (rotations about one axis only), saying why;
3. X_FC by each of OpenCV's five AX = XB methods; the one that reprojects best seeds step 4;
4. joint non-linear refinement of X_FC and X_WB minimising the reprojection error of every board
   point in every camera (left and, for a stereo rig, right through X_RC) with a robust loss;
5. per-pose residuals; the worst pose is dropped while it is an outlier (RMS above
   `outlier_factor` x the median and above `outlier_min_px`), and step 4 is repeated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

from reconstruction.boards import BoardSpec, Detection
from reconstruction.camera_model import PinholeCamera, StereoCamera
from reconstruction.errors import ScannerError
from reconstruction.rigid import (
    X_from_rvec_tvec,
    exp_se3,
    inverse,
    make_X,
    mean_pose,
    rotation_angle_rad,
    rotvec_from_rotation,
    transform_points,
)

# OpenCV's AX = XB solvers, by the names this product uses in files and on the command line.
HAND_EYE_METHODS: dict[str, int] = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}
ROBUST_LOSSES = ("linear", "huber", "soft_l1", "cauchy", "arctan")  # scipy least_squares


@dataclass(frozen=True)
class CalibrationSettings:
    """Thresholds of the calibration (units in the names).

    min_poses: hand-eye needs 3 poses (two motions about different axes); two more let the
        outlier test compare each pose with the others.
    min_motion_rotation_rad: relative rotations below this carry too little hand-eye information.
    min_axis_spread_rad: the motions' rotation axes must differ by at least this much, otherwise
        the translation along the common axis is unobservable (Tsai & Lenz 1989).
    pixel_sigma_px: standard deviation of a detected board point (px), including model error.
    robot_translation_sigma_m, robot_rotation_sigma_rad: accuracy of the reported flange poses
        (0 and 0: trust them exactly). Defaults: a calibrated 6-axis arm of the RX60's class.
    robust_loss, robust_scale: scipy least_squares loss and its scale in sigmas.
    outlier_factor, outlier_min_px: a pose is an outlier when its RMS reprojection error exceeds
        both factor x the median pose RMS and min_px.
    fix_k3: estimate only k1, k2, p1, p2 (fewer parameters for short focal-range data).
    """

    min_poses: int = 5
    min_points_per_view: int = 6
    min_motion_rotation_rad: float = math.radians(2.0)
    min_axis_spread_rad: float = math.radians(10.0)
    pixel_sigma_px: float = 0.3
    robot_translation_sigma_m: float = 0.0002
    robot_rotation_sigma_rad: float = math.radians(0.02)
    robust_loss: str = "soft_l1"
    robust_scale: float = 3.0
    outlier_factor: float = 4.0
    outlier_min_px: float = 1.0
    fix_k3: bool = False

    def __post_init__(self) -> None:
        if self.min_poses < 3:
            raise ScannerError(
                f"min_poses must be at least 3 (hand-eye needs 3), got {self.min_poses}"
            )
        if self.robust_loss not in ROBUST_LOSSES:
            raise ScannerError(
                f"robust_loss '{self.robust_loss}' is not one of {', '.join(ROBUST_LOSSES)}"
            )
        for name in ("pixel_sigma_px", "robust_scale", "outlier_factor", "outlier_min_px"):
            if not getattr(self, name) > 0:
                raise ScannerError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True, eq=False)
class PoseObservation:
    """One robot pose: its name (file or capture), the flange pose X_WF the robot reported, and
    the board points each camera found (None: board not found)."""

    name: str
    X_WF: np.ndarray
    left: Detection | None
    right: Detection | None = None

    def __post_init__(self) -> None:
        X = np.array(self.X_WF, float)
        if X.shape != (4, 4) or not np.all(np.isfinite(X)):
            raise ScannerError(f"{self.name}: X_WF must be a finite 4x4 matrix")
        if not np.allclose(X[:3, :3] @ X[:3, :3].T, np.eye(3), atol=1e-6):
            raise ScannerError(f"{self.name}: the flange rotation is not a rotation matrix")
        X.setflags(write=False)
        object.__setattr__(self, "X_WF", X)


# --------------------------------------------------------------------------------------------
# Projection (OpenCV's pinhole + k1 k2 p1 p2 k3 model), vectorised
# --------------------------------------------------------------------------------------------
def project(camera: PinholeCamera, p_S: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of points p_S (N, 3) in the camera's optical frame (same as projectPoints)."""
    x = p_S[:, 0] / p_S[:, 2]
    y = p_S[:, 1] / p_S[:, 2]
    k1, k2, p1, p2, k3 = camera.distortion
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = camera.K
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)


def _cv_points(board: BoardSpec, detection: Detection) -> tuple[np.ndarray, np.ndarray]:
    p_B = board.object_points()[detection.ids].astype(np.float32).reshape(-1, 1, 3)
    return p_B, detection.pixels.astype(np.float32).reshape(-1, 1, 2)


# --------------------------------------------------------------------------------------------
# Intrinsics and stereo
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """One camera from cv2.calibrateCamera: the model, RMS (px) and each view's RMS (px)."""

    camera: PinholeCamera
    rms_px: float
    view_rms_px: np.ndarray


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """cv2.stereoCalibrate result (intrinsics refined jointly), RMS over both cameras (px)."""

    stereo: StereoCamera
    rms_px: float
    left: CameraCalibration
    right: CameraCalibration
    view_names: tuple[str, ...]
    view_rms_px: np.ndarray  # (V, 2): left, right


def _calibration_flags(settings: CalibrationSettings) -> int:
    return cv2.CALIB_FIX_K3 if settings.fix_k3 else 0


def calibrate_camera(
    board: BoardSpec,
    detections: Sequence[Detection],
    image_size: tuple[int, int],
    settings: CalibrationSettings = CalibrationSettings(),
) -> CameraCalibration:
    """Intrinsics and distortion of one camera from board views (image_size = (width, height))."""
    if len(detections) < 3:
        raise ScannerError(
            f"camera calibration needs at least 3 views of the board, got {len(detections)}"
        )
    pairs = [_cv_points(board, d) for d in detections]
    rms, K, dist, _, _, _, _, view_errors = cv2.calibrateCameraExtended(
        [p for p, _ in pairs],
        [q for _, q in pairs],
        tuple(image_size),
        None,
        None,
        flags=_calibration_flags(settings),
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12),
    )
    camera = PinholeCamera(K, dist.ravel()[:5], int(image_size[0]), int(image_size[1]))
    return CameraCalibration(camera, float(rms), np.asarray(view_errors, float).ravel())


def calibrate_stereo(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    image_size: tuple[int, int],
    settings: CalibrationSettings = CalibrationSettings(),
) -> StereoCalibration:
    """Each camera alone, then both jointly with their relative pose (R, T) = X_RC."""
    lefts = [o.left for o in observations if o.left is not None]
    rights = [o.right for o in observations if o.right is not None]
    left = calibrate_camera(board, lefts, image_size, settings)
    right = calibrate_camera(board, rights, image_size, settings)
    names, obj, img_l, img_r = [], [], [], []
    for o in observations:
        if o.left is None or o.right is None:
            continue
        common, il, ir = np.intersect1d(o.left.ids, o.right.ids, return_indices=True)
        if len(common) < settings.min_points_per_view:
            continue
        names.append(o.name)
        obj.append(board.object_points()[common].astype(np.float32).reshape(-1, 1, 3))
        img_l.append(o.left.pixels[il].astype(np.float32).reshape(-1, 1, 2))
        img_r.append(o.right.pixels[ir].astype(np.float32).reshape(-1, 1, 2))
    if len(names) < 3:
        raise ScannerError(
            f"stereo calibration needs the board in both images of at least 3 poses, "
            f"got {len(names)}"
        )
    rms, K1, D1, K2, D2, R, T, _, _, _, _, view_errors = cv2.stereoCalibrateExtended(
        obj,
        img_l,
        img_r,
        left.camera.K.copy(),
        left.camera.distortion.copy(),
        right.camera.K.copy(),
        right.camera.distortion.copy(),
        tuple(image_size),
        np.eye(3),
        np.zeros((3, 1)),
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | _calibration_flags(settings),
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12),
    )
    w, h = int(image_size[0]), int(image_size[1])
    stereo = StereoCamera(
        PinholeCamera(K1, D1.ravel()[:5], w, h),
        PinholeCamera(K2, D2.ravel()[:5], w, h),
        R,
        T.ravel(),
    )
    return StereoCalibration(
        stereo, float(rms), left, right, tuple(names), np.asarray(view_errors, float)
    )


# --------------------------------------------------------------------------------------------
# Board poses and hand-eye
# --------------------------------------------------------------------------------------------
def board_pose(board: BoardSpec, detection: Detection, camera: PinholeCamera) -> np.ndarray:
    """X_CB by PnP: IPPE for the planar board, then Levenberg-Marquardt on all points."""
    p_B, pixels = _cv_points(board, detection)
    ok, rvec, tvec = cv2.solvePnP(p_B, pixels, camera.K, camera.distortion, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(p_B, pixels, camera.K, camera.distortion)
    rvec, tvec = cv2.solvePnPRefineLM(p_B, pixels, camera.K, camera.distortion, rvec, tvec)
    return X_from_rvec_tvec(rvec, tvec)


def hand_eye_opencv(
    X_WF: Sequence[np.ndarray], X_CB: Sequence[np.ndarray], method: str
) -> np.ndarray:
    """X_FC by one of OpenCV's calibrateHandEye methods (gripper = F, base = W, target = B)."""
    if method not in HAND_EYE_METHODS:
        raise ScannerError(
            f"unknown hand-eye method '{method}'; valid: {', '.join(HAND_EYE_METHODS)}"
        )
    try:
        R, t = cv2.calibrateHandEye(
            [X[:3, :3] for X in X_WF],
            [X[:3, 3] for X in X_WF],
            [X[:3, :3] for X in X_CB],
            [X[:3, 3] for X in X_CB],
            method=HAND_EYE_METHODS[method],
        )
    except cv2.error as e:
        # Andreff's linear system can be singular (e.g. on noise-free data).
        raise HandEyeMethodError(f"OpenCV hand-eye method '{method}' failed: {e.err}") from None
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise HandEyeMethodError(f"OpenCV hand-eye method '{method}' gave a non-finite result")
    return make_X(R, t)


class HandEyeMethodError(ScannerError):
    """One OpenCV AX = XB method failed on these poses (the others may still work)."""


def _each_method(
    X_WF: Sequence[np.ndarray], X_CB: Sequence[np.ndarray]
) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """X_FC of every OpenCV method, and the reason of each that failed."""
    estimates, failures = {}, {}
    for name in HAND_EYE_METHODS:
        try:
            estimates[name] = hand_eye_opencv(X_WF, X_CB, name)
        except HandEyeMethodError as e:
            failures[name] = str(e)
    return estimates, failures


@dataclass(frozen=True)
class MotionSummary:
    """How well the poses excite hand-eye: the largest relative rotation and the largest angle
    between the rotation axes of the motions that rotate at least min_motion_rotation_rad."""

    max_rotation_rad: float
    axis_spread_rad: float
    motions: int


def motion_summary(X_WF: Sequence[np.ndarray], min_motion_rotation_rad: float) -> MotionSummary:
    axes, max_angle = [], 0.0
    for i in range(len(X_WF)):
        for j in range(i + 1, len(X_WF)):
            R_ij = X_WF[i][:3, :3].T @ X_WF[j][:3, :3]
            angle = rotation_angle_rad(R_ij)
            max_angle = max(max_angle, angle)
            if angle >= min_motion_rotation_rad:
                # The motion's axis expressed in W, so different poses' axes are comparable.
                axis = X_WF[i][:3, :3] @ rotvec_from_rotation(R_ij)
                axes.append(axis / np.linalg.norm(axis))
    spread = 0.0
    if len(axes) >= 2:
        A = np.array(axes)
        cos = np.clip(np.abs(A @ A.T), 0.0, 1.0)
        spread = float(np.arccos(cos.min()))
    return MotionSummary(max_angle, spread, len(axes))


def check_motions(X_WF: Sequence[np.ndarray], settings: CalibrationSettings) -> MotionSummary:
    """Refuse pose sets that cannot determine X_FC, saying why (ScannerError)."""
    summary = motion_summary(X_WF, settings.min_motion_rotation_rad)
    if summary.motions == 0:
        raise ScannerError(
            f"degenerate motions: the flange orientations differ by at most "
            f"{math.degrees(summary.max_rotation_rad):.2f} deg; hand-eye calibration needs "
            f"rotations of at least {math.degrees(settings.min_motion_rotation_rad):.1f} deg "
            "between poses (pure translations leave the camera's rotation offset unobservable)"
        )
    if summary.axis_spread_rad < settings.min_axis_spread_rad:
        raise ScannerError(
            f"degenerate motions: all rotations between poses are about one axis (their axes "
            f"differ by at most {math.degrees(summary.axis_spread_rad):.1f} deg, need "
            f"{math.degrees(settings.min_axis_spread_rad):.0f} deg); the hand-eye translation "
            "along that axis is then unobservable: add poses that tilt about another axis"
        )
    return summary


# --------------------------------------------------------------------------------------------
# Joint refinement over X_FC and X_WB
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _SensorPoints:
    camera: PinholeCamera
    X_SC: np.ndarray  # this sensor's frame S seen from the left camera C
    pose_index: np.ndarray  # (N,) which observation each point belongs to
    p_B: np.ndarray  # (N, 3)
    pixels: np.ndarray  # (N, 2)


def _sensors(
    board: BoardSpec, observations: Sequence[PoseObservation], cameras: StereoCamera | PinholeCamera
) -> list[_SensorPoints]:
    if isinstance(cameras, StereoCamera):
        rigs = [(cameras.left, np.eye(4), "left"), (cameras.right, inverse(cameras.X_CR), "right")]
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
                _SensorPoints(camera, X_SC, np.concatenate(idx), np.vstack(p_B), np.vstack(px))
            )
    return out


def _reprojection(
    sensors: list[_SensorPoints], X_WF: np.ndarray, X_FC: np.ndarray, X_WB: np.ndarray
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
        out.append(s.pixels - project(s.camera, p_S))
    return out


def _pose_rms(
    sensors: list[_SensorPoints], residuals: list[np.ndarray], n_poses: int
) -> np.ndarray:
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


def _jacobian_sparsity(sensors: list[_SensorPoints], n_poses: int, with_corrections: bool):
    from scipy.sparse import lil_matrix

    n_pixels = sum(2 * len(s.pose_index) for s in sensors)
    n_params = 12 + (6 * n_poses if with_corrections else 0)
    n_rows = n_pixels + (6 * n_poses if with_corrections else 0)
    J = lil_matrix((n_rows, n_params), dtype=int)
    J[:n_pixels, :12] = 1
    if with_corrections:
        row = 0
        for s in sensors:
            for k in s.pose_index:
                J[row : row + 2, 12 + 6 * k : 18 + 6 * k] = 1
                row += 2
        for k in range(n_poses):
            J[n_pixels + 6 * k : n_pixels + 6 * k + 6, 12 + 6 * k : 18 + 6 * k] = np.eye(
                6, dtype=int
            )
    return J


def refine_hand_eye(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    X_FC0: np.ndarray,
    X_WB0: np.ndarray,
    settings: CalibrationSettings = CalibrationSettings(),
) -> Refinement:
    """Maximum-likelihood X_FC and X_WB: reprojection errors of every board point in every
    camera (sigma pixel_sigma_px) and, when the robot sigmas are positive, a small correction
    of every reported flange pose with its prior (robot_*_sigma). Without the corrections a
    robot's own pose errors (0.02 deg is 0.3 mm at 0.85 m) are absorbed by X_FC, which far
    from the board and with small tilts moves it by centimetres along weakly observed
    directions; with them the images decide what they measure well (lateral position) and the
    robot's accuracy bounds the rest. A robust loss (in sigmas) limits the pull of bad points.

    Poses are parameterised as X0 @ exp(xi): small, well-scaled parameters near the seed.
    """
    sensors = _sensors(board, observations, cameras)
    X_WF = np.array([o.X_WF for o in observations])
    n = len(observations)
    corrections = settings.robot_translation_sigma_m > 0 and settings.robot_rotation_sigma_rad > 0
    prior_scale = np.r_[
        np.full(3, 1 / max(settings.robot_rotation_sigma_rad, 1e-12)),
        np.full(3, 1 / max(settings.robot_translation_sigma_m, 1e-12)),
    ]

    def unpack(x):
        X_FC = X_FC0 @ exp_se3(x[:6])
        X_WB = X_WB0 @ exp_se3(x[6:12])
        xi = x[12:].reshape(n, 6) if corrections else np.zeros((n, 6))
        return X_FC, X_WB, xi

    def corrected(xi):
        return np.array([X @ exp_se3(d) for X, d in zip(X_WF, xi)]) if corrections else X_WF

    def fun(x):
        X_FC, X_WB, xi = unpack(x)
        pixels = _reprojection(sensors, corrected(xi), X_FC, X_WB)
        parts = [r.ravel() / settings.pixel_sigma_px for r in pixels]
        if corrections:
            parts.append((xi * prior_scale).ravel())
        return np.concatenate(parts)

    result = least_squares(
        fun,
        np.zeros(12 + (6 * n if corrections else 0)),
        jac_sparsity=_jacobian_sparsity(sensors, n, corrections),
        loss=settings.robust_loss,
        f_scale=settings.robust_scale,
        x_scale="jac",
        method="trf",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=100,
    )
    X_FC, X_WB, xi = unpack(result.x)
    residuals = _reprojection(sensors, X_WF, X_FC, X_WB)
    corrected = _reprojection(sensors, corrected(xi), X_FC, X_WB)
    return Refinement(
        X_FC,
        X_WB,
        _rms(residuals),
        _pose_rms(sensors, residuals, n),
        xi,
        _rms(corrected),
        int(result.nfev),
    )


def _rms(residuals: list[np.ndarray]) -> float:
    return float(np.sqrt(np.concatenate([np.sum(r * r, axis=1) for r in residuals]).mean()))


# --------------------------------------------------------------------------------------------
# The whole hand-eye calibration
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PoseResidual:
    """One pose's outcome: RMS reprojection error (px) under the final X_FC and X_WB (NaN when
    the board was not found) and its status: "used", "outlier" or "board not found"."""

    name: str
    rms_px: float
    status: str


@dataclass(frozen=True, eq=False)
class HandEyeCalibration:
    """Result of `calibrate_hand_eye`.

    X_FC: refined hand-eye pose (left camera in flange); X_WB: refined board pose in the base.
    opencv: X_FC of each OpenCV method alone, on the poses finally used; seed_method: the one
    that seeded the refinement. board_scatter_m: per-axis standard deviation (m) of the board
    origin mapped into W through each used pose (X_WF_i X_FC X_CB_i): the self-consistency a
    user can check without ground truth. rms_px: reprojection RMS of the used poses with the
    robot poses as reported; corrected_rms_px: after the small robot-pose corrections the
    estimate implies (robot_corrections, (6,) per used pose: rotation vector rad, translation m).
    """

    X_FC: np.ndarray
    X_WB: np.ndarray
    rms_px: float
    corrected_rms_px: float
    opencv: dict[str, np.ndarray]
    seed_method: str
    residuals: tuple[PoseResidual, ...]
    board_scatter_m: np.ndarray
    board_scatter_max_m: float
    motion: MotionSummary
    X_CB: dict[str, np.ndarray] = field(default_factory=dict)
    robot_corrections: dict[str, np.ndarray] = field(default_factory=dict)
    opencv_failed: dict[str, str] = field(default_factory=dict)

    @property
    def used(self) -> list[str]:
        return [r.name for r in self.residuals if r.status == "used"]

    @property
    def outliers(self) -> list[str]:
        return [r.name for r in self.residuals if r.status == "outlier"]

    @property
    def not_found(self) -> list[str]:
        return [r.name for r in self.residuals if r.status == "board not found"]


def _left_camera(cameras: StereoCamera | PinholeCamera) -> PinholeCamera:
    return cameras.left if isinstance(cameras, StereoCamera) else cameras


def require_poses(usable: int, total: int, missing: Sequence[str], need: int) -> None:
    """ScannerError saying how many more poses to record, and why, when usable < need."""
    if usable >= need:
        return
    why = f"; the board was not found in: {', '.join(missing)}" if missing else ""
    raise ScannerError(
        f"only {usable} of {total} poses are usable, calibration needs at least {need} (hand-eye "
        f"needs 3, the outlier test {need - 3} more): record {need - usable} more pose(s) with "
        f"the whole board in view{why}"
    )


def board_scatter(
    X_WF: Sequence[np.ndarray], X_FC: np.ndarray, X_CB: Sequence[np.ndarray]
) -> tuple[np.ndarray, float]:
    """Per-axis std (m) and the largest distance from the mean (m) of the board origins in W."""
    p = np.array([(Xf @ X_FC @ Xc)[:3, 3] for Xf, Xc in zip(X_WF, X_CB)])
    return p.std(axis=0), float(np.linalg.norm(p - p.mean(axis=0), axis=1).max())


def _seed(
    board: BoardSpec,
    obs: list[PoseObservation],
    X_CB: list[np.ndarray],
    cameras: StereoCamera | PinholeCamera,
) -> tuple[dict[str, np.ndarray], str, np.ndarray]:
    """Every OpenCV method; the seed is the one whose X_FC (with the mean board pose it implies)
    reprojects best by the median pose RMS (robust to a few bad poses)."""
    X_WF = [o.X_WF for o in obs]
    sensors = _sensors(board, obs, cameras)
    estimates, failures = _each_method(X_WF, X_CB)
    if not estimates:
        raise ScannerError(
            "hand-eye calibration failed: every OpenCV method failed ("
            + "; ".join(failures.values())
            + ")"
        )
    scores, boards = {}, {}
    for name, X_FC in estimates.items():
        X_WB = mean_pose([Xf @ X_FC @ Xc for Xf, Xc in zip(X_WF, X_CB)])
        residuals = _reprojection(sensors, np.array(X_WF), X_FC, X_WB)
        boards[name] = X_WB
        scores[name] = float(np.median(_pose_rms(sensors, residuals, len(obs))))
    best = min(scores, key=scores.get)
    return estimates, best, boards[best]


def calibrate_hand_eye(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    settings: CalibrationSettings = CalibrationSettings(),
) -> HandEyeCalibration:
    """X_FC (and X_WB) from robot poses and board detections; see the module docstring."""
    usable = [
        o
        for o in observations
        if o.left is not None and len(o.left) >= settings.min_points_per_view
    ]
    missing = [o.name for o in observations if o not in usable]
    require_poses(len(usable), len(observations), missing, settings.min_poses)
    left = _left_camera(cameras)
    X_CB = {o.name: board_pose(board, o.left, left) for o in usable}
    motion = check_motions([o.X_WF for o in usable], settings)
    _, seed_method, X_WB = _seed(board, usable, [X_CB[o.name] for o in usable], cameras)
    X_FC = hand_eye_opencv([o.X_WF for o in usable], [X_CB[o.name] for o in usable], seed_method)

    inliers = list(usable)
    outliers: list[PoseObservation] = []
    while True:
        refined = refine_hand_eye(board, inliers, cameras, X_FC, X_WB, settings)
        X_FC, X_WB = refined.X_FC, refined.X_WB
        rms = refined.pose_rms_px
        limit = max(settings.outlier_min_px, settings.outlier_factor * float(np.median(rms)))
        worst = int(np.argmax(rms))
        if rms[worst] <= limit or len(inliers) <= settings.min_poses:
            break
        outliers.append(inliers.pop(worst))

    # Final residuals of every pose (outliers too) under the final estimate.
    sensors_all = _sensors(board, usable, cameras)
    rms_all = _pose_rms(
        sensors_all,
        _reprojection(sensors_all, np.array([o.X_WF for o in usable]), X_FC, X_WB),
        len(usable),
    )
    by_name = {o.name: float(r) for o, r in zip(usable, rms_all)}
    residuals = []
    for o in observations:
        if o.name in missing:
            residuals.append(PoseResidual(o.name, float("nan"), "board not found"))
        elif o in outliers:
            residuals.append(PoseResidual(o.name, by_name[o.name], "outlier"))
        else:
            residuals.append(PoseResidual(o.name, by_name[o.name], "used"))
    X_WF_in = [o.X_WF for o in inliers]
    X_CB_in = [X_CB[o.name] for o in inliers]
    opencv, opencv_failed = _each_method(X_WF_in, X_CB_in)
    scatter, scatter_max = board_scatter(X_WF_in, X_FC, X_CB_in)
    return HandEyeCalibration(
        X_FC,
        X_WB,
        refined.rms_px,
        refined.corrected_rms_px,
        opencv,
        seed_method,
        tuple(residuals),
        scatter,
        scatter_max,
        motion,
        X_CB,
        {o.name: xi for o, xi in zip(inliers, refined.corrections)},
        opencv_failed,
    )

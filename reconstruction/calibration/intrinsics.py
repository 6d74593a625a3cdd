"""Intrinsics and distortion of one camera (cv2.calibrateCamera) and of a stereo pair with its
relative pose (cv2.stereoCalibrate, intrinsics refined jointly)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.calibration.boards import BoardSpec, Detection
from reconstruction.calibration.observations import PoseObservation, board_correspondences
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera


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
    pairs = [board_correspondences(board, d) for d in detections]
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

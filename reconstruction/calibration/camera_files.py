"""Cameras read from other systems' files: the checks every reader shares (a distortion
vector the product's model holds, a camera and a stereo pair built with the file named in the
error)."""

from __future__ import annotations

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import CameraModelError, PinholeCamera, StereoCamera

# OpenCV's distortion vector lengths (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]); the
# product's model has the first five, so longer vectors are taken only when the rest is zero.
OPENCV_DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


def distortion5(values: np.ndarray, where: str) -> np.ndarray:
    d = np.asarray(values, float).ravel()
    if len(d) not in OPENCV_DISTORTION_LENGTHS:
        raise ScannerError(
            f"{where}: expected {', '.join(map(str, OPENCV_DISTORTION_LENGTHS))} distortion "
            f"coefficients, got {len(d)}"
        )
    if np.any(d[5:] != 0):
        raise ScannerError(
            f"{where}: coefficients beyond k1 k2 p1 p2 k3 are not zero ({d[5:].tolist()}); the "
            "camera model here has k1 k2 p1 p2 k3 only, recalibrate without the rational or "
            "thin-prism terms"
        )
    return np.concatenate([d[:5], np.zeros(5 - min(len(d), 5))])


def stereo_from(left: PinholeCamera, right: PinholeCamera, R, T, where: str) -> StereoCamera:
    try:
        return StereoCamera(left, right, R, T)
    except CameraModelError as e:
        raise ScannerError(f"{where}: {e}") from None


def camera_from(K, distortion, size: tuple[int, int], where: str) -> PinholeCamera:
    try:
        return PinholeCamera(K, distortion, int(size[0]), int(size[1]))
    except CameraModelError as e:
        raise ScannerError(f"{where}: {e}") from None

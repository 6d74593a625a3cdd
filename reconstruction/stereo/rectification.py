"""Undistortion + rectification of a stereo pair, computed once per camera model and reused."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera


@dataclass(frozen=True, eq=False)
class Rectification:
    """cv2.stereoRectify outputs and the remap tables.

    R1: rotation from the original left frame C to the rectified left frame (p_rect = R1 @ p_C).
    P1, P2: 3x4 projections of the rectified cameras; Q: 4x4 disparity-to-depth matrix.
    maps_left, maps_right: cv2.remap tables (fixed point, fast). source_px_left: (H, W, 2)
    float32, the original (distorted) left pixel (u, v) that each rectified left pixel samples.
    """

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    maps_left: tuple[np.ndarray, np.ndarray]
    maps_right: tuple[np.ndarray, np.ndarray]
    image_size: tuple[int, int]
    source_px_left: np.ndarray

    @property
    def focal_px(self) -> float:
        return float(self.P1[0, 0])

    @property
    def baseline_m(self) -> float:
        return float(-self.P2[0, 3] / self.P2[0, 0])


def compute_rectification(model: StereoCamera, alpha: float = 0.0) -> Rectification:
    """alpha = 0 keeps only valid pixels (no black borders), 1 keeps every source pixel."""
    size = model.image_size
    L, Rc = model.left, model.right
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        L.K,
        L.distortion,
        Rc.K,
        Rc.distortion,
        size,
        model.R,
        model.T,
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=alpha,
    )
    return rectification_of(L, Rc, R1, R2, P1, P2, Q, size)


def rectification_of(
    left: PinholeCamera,
    right: PinholeCamera,
    R1: np.ndarray,
    R2: np.ndarray,
    P1: np.ndarray,
    P2: np.ndarray,
    Q: np.ndarray,
    size: tuple[int, int],
) -> Rectification:
    """The record of rectifying rotations and projections (cv2.stereoRectify's, or a pair's own
    grid), with its remap tables onto the rectified grid of `size` (width, height)."""
    source_px_left = cv2.initUndistortRectifyMap(
        left.K, left.distortion, R1, P1, size, cv2.CV_32FC2
    )[0]
    maps_left = cv2.convertMaps(source_px_left, None, cv2.CV_16SC2)
    maps_right = cv2.initUndistortRectifyMap(right.K, right.distortion, R2, P2, size, cv2.CV_16SC2)
    for a in (R1, R2, P1, P2, Q, source_px_left, *maps_left, *maps_right):
        a.setflags(write=False)
    return Rectification(R1, R2, P1, P2, Q, maps_left, maps_right, size, source_px_left)


def rectify_pair(
    rect: Rectification, left: np.ndarray, right: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Undistort and rectify both images (any channel count, same size as the model)."""
    for name, image in (("left", left), ("right", right)):
        if image.shape[1::-1] != rect.image_size:
            raise ScannerError(
                f"{name} image is {image.shape[1]}x{image.shape[0]}, the camera model expects "
                f"{rect.image_size[0]}x{rect.image_size[1]}"
            )
    return (
        cv2.remap(left, *rect.maps_left, cv2.INTER_LINEAR),
        cv2.remap(right, *rect.maps_right, cv2.INTER_LINEAR),
    )

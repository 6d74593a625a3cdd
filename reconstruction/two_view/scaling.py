"""Downscaled views: image, mask and the camera that sees the smaller image.

Real cameras resolve far more disparity than a pair needs: DTU's 1600x1200 views (fx 2890 px,
0.12 m apart at 0.65 m) have disparities of about 500 px and a search of over 400 px for the
working volume, where a 2x smaller image halves both and matches 8x faster. The camera follows
the image exactly: pixel centres, not corners, map onto each other
(u' + 1/2 = (u + 1/2) / s, what cv2.resize's INTER_AREA does).
"""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import PinholeCamera


def scaled_size(width: int, height: int, factor: float) -> tuple[int, int]:
    """(width, height) of an image downscaled by `factor` (>= 1)."""
    if not factor >= 1.0:
        raise ScannerError(f"two_view.downscale: must be at least 1, got {factor}")
    return max(int(round(width / factor)), 1), max(int(round(height / factor)), 1)


def downscaled_camera(camera: PinholeCamera, factor: float) -> PinholeCamera:
    """The camera of the image `downscaled_image(image, factor)`. Distortion coefficients act on
    normalised coordinates and stay as they are."""
    width, height = scaled_size(camera.width, camera.height, factor)
    sx, sy = camera.width / width, camera.height / height
    K = camera.K.copy()
    K[0, :] = [K[0, 0] / sx, K[0, 1] / sx, (K[0, 2] + 0.5) / sx - 0.5]
    K[1, 1:] = [K[1, 1] / sy, (K[1, 2] + 0.5) / sy - 0.5]
    return PinholeCamera(K, camera.distortion, width, height)


def downscaled_image(image: np.ndarray, factor: float) -> np.ndarray:
    """The image averaged down by `factor` (INTER_AREA: no aliasing of fine texture)."""
    size = scaled_size(image.shape[1], image.shape[0], factor)
    if size == (image.shape[1], image.shape[0]):
        return image
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def downscaled_mask(mask: np.ndarray, factor: float) -> np.ndarray:
    """A boolean mask downscaled like its image: a pixel is in when most of what it covers is."""
    grey = downscaled_image(np.asarray(mask, bool).astype(np.uint8) * 255, factor)
    return grey > 127

"""How good a camera (or stereo) calibration is, from its board views alone: the rectified
epipolar error of the corners both cameras saw, and how much of the image the boards covered.

The epipolar error is what stereo matching feels: after rectification a board corner must lie
on the same row in both images; SGBM searches along rows only, so a row error beyond ~1 px loses
matches. Coverage says whether the distortion model was constrained where the image is used:
corners only in the middle leave the borders extrapolated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.calibration.boards import Detection
from reconstruction.calibration.observations import PoseObservation
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera
from reconstruction.stereo.rectification import compute_rectification


@dataclass(frozen=True)
class EpipolarError:
    """|row difference| (px) of every corner both rectified images hold."""

    median_px: float
    p95_px: float
    max_px: float
    corners: int


def _rectified_px(
    pixels: np.ndarray, camera: PinholeCamera, R: np.ndarray, P: np.ndarray
) -> np.ndarray:
    """(N, 2) pixels of one camera, undistorted and mapped into its rectified image (R, P from
    cv2.stereoRectify)."""
    return cv2.undistortPoints(
        pixels.reshape(-1, 1, 2), camera.K, camera.distortion, R=R, P=P
    ).reshape(-1, 2)


def epipolar_error(stereo: StereoCamera, observations: Sequence[PoseObservation]) -> EpipolarError:
    """The row disagreement of common corners after undistortion and rectification."""
    rect = compute_rectification(stereo)
    rows = []
    for o in observations:
        if o.left is None or o.right is None:
            continue
        _, il, ir = np.intersect1d(o.left.ids, o.right.ids, return_indices=True)
        if len(il) == 0:
            continue
        left = _rectified_px(o.left.pixels[il], stereo.left, rect.R1, rect.P1)
        right = _rectified_px(o.right.pixels[ir], stereo.right, rect.R2, rect.P2)
        rows.append(np.abs(left[:, 1] - right[:, 1]))
    if not rows:
        return EpipolarError(float("nan"), float("nan"), float("nan"), 0)
    d = np.concatenate(rows)
    return EpipolarError(
        float(np.median(d)), float(np.percentile(d, 95)), float(d.max()), int(len(d))
    )


def board_coverage(detections: Sequence[Detection], image_size: tuple[int, int]) -> float:
    """The share of the image inside the convex hull of some view's detected board points."""
    scale = 8  # an 8 px raster is far finer than any board
    width, height = image_size
    mask = np.zeros((max(height // scale, 1), max(width // scale, 1)), np.uint8)
    for d in detections:
        if len(d.pixels) >= 3:
            hull = cv2.convexHull((d.pixels / scale).astype(np.float32)).astype(np.int32)
            cv2.fillConvexPoly(mask, hull, 1)
    return float(mask.mean())

"""Accuracy of one stereo cloud against a true depth image (simulator ground truth).

The true z-depth and object mask live on the ORIGINAL (distorted) left sensor grid, like the
images. Each cloud point carries the distorted left pixel its ray goes through, so its depth
along C's z axis is compared with the true depth interpolated at that pixel. Coverage is counted
on the rectified left grid, where the disparity lives.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.stereo.cloud import StereoCloud, sample_image
from reconstruction.stereo.rectification import Rectification

# A left pixel counts as hidden from the right camera when something lands within this many
# pixels left of its match: half a pixel is the resolution of the right image itself.
OCCLUSION_TOLERANCE_PX = 0.5


@dataclass(frozen=True, eq=False)
class StereoAccuracy:
    """depth_errors_m: (M,) signed z error (measured - true) of the cloud's object points.

    valid_fraction: share of the object's pixels in the rectified left image that got a point.
    valid_fraction_both_visible: the same over object pixels the right camera sees too (the
    others cannot be matched by any stereo method).
    background_false_valid_fraction: share of rectified pixels whose true depth lies outside the
    depth window (sky, far walls) that nevertheless got a point.
    """

    depth_errors_m: np.ndarray
    valid_fraction: float
    valid_fraction_both_visible: float
    background_false_valid_fraction: float
    object_pixels: int
    background_pixels: int

    @property
    def median_abs_error_m(self) -> float:
        return float(np.median(np.abs(self.depth_errors_m)))

    @property
    def p90_abs_error_m(self) -> float:
        return float(np.percentile(np.abs(self.depth_errors_m), 90))


def true_disparity(rect: Rectification, depth_C_m: np.ndarray) -> np.ndarray:
    """True disparity (px, NaN = nothing) on the rectified left grid from the true z-depth in C.

    A rectified pixel's ray is r = ((u - cx) / f, (v - cy) / f, 1) in the rectified frame; its
    point at rectified depth Z has C depth Z (R1^T r)_z, and d = f b / Z.
    """
    height, width = rect.source_px_left.shape[:2]
    depth = np.where(np.isfinite(depth_C_m), depth_C_m, np.nan).astype(np.float32)
    z_C = sample_image(depth, rect.source_px_left.reshape(-1, 2), cv2.INTER_NEAREST)
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    f, cx, cy = rect.P1[0, 0], rect.P1[0, 2], rect.P1[1, 2]
    rays = np.stack([(u.ravel() - cx) / f, (v.ravel() - cy) / f, np.ones(u.size)], axis=1)
    z_rect = z_C / (rays @ rect.R1[:, 2])
    return (rect.focal_px * rect.baseline_m / z_rect).reshape(height, width).astype(np.float32)


def hidden_from_right(disparity_true: np.ndarray) -> np.ndarray:
    """Left pixels whose surface point the right camera cannot see (half-occlusions).

    Visible pixels of a row keep their order in the right image (x_r = u - d increases with u);
    a pixel whose x_r is not left of every x_r further right in the row is covered there.
    """
    x_right = np.arange(disparity_true.shape[1])[None, :] - disparity_true
    x_right = np.where(np.isfinite(x_right), x_right, np.inf)
    min_from_right = np.minimum.accumulate(x_right[:, ::-1], axis=1)[:, ::-1]
    min_strictly_right = np.concatenate(
        [min_from_right[:, 1:], np.full((x_right.shape[0], 1), np.inf)], axis=1
    )
    return np.isfinite(disparity_true) & (x_right >= min_strictly_right - OCCLUSION_TOLERANCE_PX)


def stereo_accuracy(
    rect: Rectification,
    cloud: StereoCloud,
    depth_true_m: np.ndarray,
    object_mask: np.ndarray,
    z_min_m: float,
    z_max_m: float,
) -> StereoAccuracy:
    """Compare a cloud with the true z-depth in C (inf = nothing) and the object mask, both on
    the original left sensor grid; [z_min_m, z_max_m] is the depth window the cloud used."""
    # NaN wherever nothing was hit, so that bilinear lookups straddling a silhouette give NaN.
    depth = np.where(np.isfinite(depth_true_m), depth_true_m, np.nan).astype(np.float32)
    mask = object_mask.astype(np.uint8)
    z_true = sample_image(depth, cloud.pixels_left, cv2.INTER_LINEAR)
    on_object = sample_image(mask, cloud.pixels_left, cv2.INTER_NEAREST) > 0
    compared = on_object & np.isfinite(z_true)
    errors = cloud.points_C[compared, 2] - z_true[compared]

    height, width = rect.source_px_left.shape[:2]
    source = rect.source_px_left.reshape(-1, 2)
    object_rect = sample_image(mask, source, cv2.INTER_NEAREST).reshape(height, width) > 0
    depth_rect = sample_image(depth, source, cv2.INTER_NEAREST).reshape(height, width)
    with np.errstate(invalid="ignore"):
        background = ~((depth_rect >= z_min_m) & (depth_rect <= z_max_m))
    both_visible = object_rect & ~hidden_from_right(true_disparity(rect, depth_true_m))
    has_point = np.zeros((height, width), bool)
    u, v = np.rint(cloud.pixels_rect).astype(np.int64).T
    has_point[v, u] = True

    def share(region: np.ndarray) -> float:
        return float(has_point[region].mean()) if region.any() else 0.0

    return StereoAccuracy(
        errors,
        share(object_rect),
        share(both_visible),
        share(background),
        int(object_rect.sum()),
        int(background.sum()),
    )

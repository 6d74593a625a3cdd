"""A depth image -> points in the colour frame C, coloured by the colour image, and the depth map
for fusion: what every RGB-D capture goes through, as `view_cloud` is for a stereo pair.

The depth camera D and the colour camera C are two cameras: each depth pixel is lifted with the
depth camera's intrinsics and the depth unit, moved into C with the device's extrinsics X_CD,
and coloured where it projects into the colour image (texture agreement in the alignment of
hangings depends on that colour being the right one). Only the depths the object can occupy are
kept, as for the stereo pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import transform_points
from reconstruction.depth.camera_model import RgbdCamera
from reconstruction.registration.views import DepthImage
from reconstruction.stereo.cloud import sample_image
from reconstruction.stereo.params import object_depth_window


@dataclass(frozen=True, eq=False)
class DepthCloud:
    """points_C (N, 3) metres in the colour frame; colors (N, 3) uint8; pixels_D (N, 2) the
    depth pixels they came from; depth: the kept depths on the depth grid (for TSDF)."""

    points_C: np.ndarray
    colors: np.ndarray
    pixels_D: np.ndarray
    depth: DepthImage

    def __len__(self) -> int:
        return len(self.points_C)


def check_rgbd_images(camera: RgbdCamera, depth: np.ndarray, color: np.ndarray) -> None:
    """Images of the sizes and kinds the device model says, else one line naming which."""
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ScannerError(
            f"depth image: expected (H, W) uint16 counts, got {depth.dtype} {depth.shape}"
        )
    if depth.shape[::-1] != camera.depth_size:
        raise ScannerError(
            f"depth image is {depth.shape[1]}x{depth.shape[0]}, the depth camera's is "
            f"{camera.depth_size[0]}x{camera.depth_size[1]}"
        )
    if color.ndim != 3 or color.shape[2] != 3 or color.shape[1::-1] != camera.image_size:
        raise ScannerError(
            f"colour image is {color.shape[1]}x{color.shape[0]}, the colour camera's is "
            f"{camera.image_size[0]}x{camera.image_size[1]}"
        )


def depth_points_D(camera: RgbdCamera, depth_m: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N, 3) points in D of depth pixels (u, v) at depths (N,) metres (along D's optical
    axis), through the depth camera's intrinsics and distortion."""
    cam = camera.depth
    if np.any(cam.distortion):
        xy = cv2.undistortPoints(
            pixels.reshape(-1, 1, 2).astype(np.float64), cam.K, cam.distortion
        ).reshape(-1, 2)
    else:
        K = cam.K
        xy = np.stack(
            [(pixels[:, 0] - K[0, 2]) / K[0, 0], (pixels[:, 1] - K[1, 2]) / K[1, 1]], axis=1
        )
    return np.column_stack([xy * depth_m[:, None], depth_m])


def rgbd_cloud(
    camera: RgbdCamera,
    depth_counts: np.ndarray,
    color: np.ndarray,
    z_min_m: float,
    z_max_m: float,
    step_px: int = 1,
) -> DepthCloud:
    """The cloud of one RGB-D capture: depths in [z_min_m, z_max_m] (and the device's range)
    lifted into C and coloured; depth pixels whose point falls outside the colour image have
    no colour and are dropped. step_px: every step_px-th pixel (a live preview)."""
    check_rgbd_images(camera, depth_counts, color)
    z = depth_counts.astype(np.float64) * (camera.depth_scale_m * camera.depth_correction)
    lo, hi = max(z_min_m, camera.min_depth_m), min(z_max_m, camera.max_depth_m)
    keep = (depth_counts > 0) & (z >= lo) & (z <= hi)
    if step_px > 1:
        grid = np.zeros_like(keep)
        grid[::step_px, ::step_px] = True
        keep &= grid
    v, u = np.nonzero(keep)
    pixels_D = np.column_stack([u, v]).astype(np.float64)
    p_C = transform_points(camera.X_CD, depth_points_D(camera, z[v, u], pixels_D))
    uv_color = _project(camera, p_C)
    w, h = camera.image_size
    seen = (
        (p_C[:, 2] > 0)
        & (uv_color[:, 0] >= 0)
        & (uv_color[:, 0] <= w - 1)
        & (uv_color[:, 1] >= 0)
        & (uv_color[:, 1] <= h - 1)
    )
    colors = sample_image(color, uv_color[seen].astype(np.float32), cv2.INTER_LINEAR)
    depth_m = np.zeros(depth_counts.shape, np.float32)
    depth_m[v[seen], u[seen]] = z[v[seen], u[seen]]
    depth = DepthImage(depth_m, camera.depth.K, camera.X_CD)
    return DepthCloud(p_C[seen], np.asarray(colors, np.uint8).reshape(-1, 3), pixels_D[seen], depth)


def _project(camera: RgbdCamera, p_C: np.ndarray) -> np.ndarray:
    if len(p_C) == 0:
        return np.zeros((0, 2))
    uv, _ = cv2.projectPoints(
        p_C.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.color.K, camera.color.distortion
    )
    return uv.reshape(-1, 2)


def view_rgbd_cloud(
    camera: RgbdCamera,
    depth_counts: np.ndarray,
    color: np.ndarray,
    X_WC: np.ndarray,
    p_W_centre: np.ndarray,
    radius_m: float,
    step_px: int = 1,
) -> DepthCloud:
    """The cloud of one capture of an object within radius_m of p_W_centre, the colour camera
    at X_WC: only the depths the object can occupy are kept (measured from the depth camera)."""
    X_WD = X_WC @ camera.X_CD
    distance = float(np.linalg.norm(np.asarray(p_W_centre, float) - X_WD[:3, 3]))
    z_min, z_max = object_depth_window(distance, radius_m)
    return rgbd_cloud(camera, depth_counts, color, z_min, z_max, step_px)

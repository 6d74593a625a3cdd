"""Disparities -> points in the ORIGINAL left optical frame C; depth maps for fusion.

`view_cloud` is what every capture goes through (at the end of a scan, offline, and live in
Meshcat): the depth window comes from where the camera is and how large the object can be, the
pair is rectified and matched over that window, and the valid disparities are lifted into C.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.registration.views import DepthImage
from reconstruction.stereo.matching import check_pair, disparity_image, grey_image
from reconstruction.stereo.params import StereoParams, disparity_window, object_depth_window
from reconstruction.stereo.rectification import Rectification, rectify_pair


@dataclass(frozen=True, eq=False)
class StereoCloud:
    """Points seen by one stereo pair, in the ORIGINAL left optical frame C.

    points_C: (N, 3) float64 metres. colors: (N, 3) uint8 RGB from the left image.
    pixels_rect: (N, 2) float32 (u, v) of each point in the rectified left image.
    pixels_left: (N, 2) float32 (u, v) in the original (distorted) left image.
    """

    points_C: np.ndarray
    colors: np.ndarray
    pixels_rect: np.ndarray
    pixels_left: np.ndarray

    def __post_init__(self) -> None:
        for a in (self.points_C, self.colors, self.pixels_rect, self.pixels_left):
            a.setflags(write=False)

    def __len__(self) -> int:
        return len(self.points_C)


def points_from_disparity(rect: Rectification, uvd: np.ndarray) -> np.ndarray:
    """(N, 3) rectified left pixels and disparities (u, v, d) -> (N, 3) points p_C in metres.

    Q lifts (u, v, d) into the rectified left frame (what cv2.reprojectImageTo3D does per pixel,
    here on valid pixels only); R1 rotates C into that frame, so p_C = R1^T p_rect.
    """
    uvd = np.asarray(uvd, np.float64).reshape(-1, 1, 3)
    if len(uvd) == 0:
        return np.zeros((0, 3))
    p_rect = cv2.perspectiveTransform(uvd, rect.Q)[:, 0, :]
    return p_rect @ rect.R1


def reproject(
    rect: Rectification,
    disparity: np.ndarray,
    left_image: np.ndarray,
    z_min_m: float,
    z_max_m: float,
    subsample_step_px: int = 1,
) -> StereoCloud:
    """Points of the valid disparities (rectified left grid) whose rectified depth f b / d lies
    in [z_min_m, z_max_m], in frame C, with colours and pixel coordinates.

    left_image: the ORIGINAL (distorted) left image, grey or RGB; colours are sampled at each
    point's source pixel, so only the points are resampled, not the whole image.
    subsample_step_px: use every n-th row and column of the disparity image.
    """
    step = subsample_step_px
    sub = disparity[::step, ::step]
    v, u = np.nonzero(np.isfinite(sub))
    d = sub[v, u].astype(np.float64)
    # Z = f b / d in the rectified frame (Q with CALIB_ZERO_DISPARITY): the window is a range of d.
    fb = rect.focal_px * rect.baseline_m
    in_window = (d >= fb / z_max_m) & (d <= fb / z_min_m)
    u, v, d = u[in_window] * step, v[in_window] * step, d[in_window]
    points_C = points_from_disparity(rect, np.stack([u, v, d], axis=1))
    pixels_left = rect.source_px_left[v, u]
    colors = sample_image(left_image, pixels_left, cv2.INTER_LINEAR)
    if colors.ndim == 1 or colors.shape[1] == 1:
        colors = np.repeat(colors.reshape(-1, 1), 3, axis=1)
    pixels_rect = np.stack([u, v], axis=1).astype(np.float32)
    return StereoCloud(points_C, colors.astype(np.uint8), pixels_rect, pixels_left)


def sample_image(image: np.ndarray, pixels: np.ndarray, interpolation: int) -> np.ndarray:
    """image at (N, 2) float pixels (u, v) -> (N,) or (N, channels); outside: NaN or 0.

    cv2.remap needs images shorter than 32767 columns, so the N lookups are laid out in rows.
    """
    row = 1024
    n = len(pixels)
    if n == 0:
        return np.zeros((0, *image.shape[2:]), image.dtype)
    padded = np.zeros((-(-n // row) * row, 2), np.float32)
    padded[:n] = pixels
    maps = padded.reshape(-1, row, 2)
    border = np.nan if image.dtype.kind == "f" else 0
    out = cv2.remap(
        image, maps, None, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=border
    )
    return out.reshape(-1, *image.shape[2:])[:n]


def stereo_cloud(
    rect: Rectification,
    left: np.ndarray,
    right: np.ndarray,
    z_min_m: float,
    z_max_m: float,
    params: StereoParams | None = None,
) -> StereoCloud:
    """The cloud of a RAW (distorted) pair: rectify, SGBM over the depth window, reproject.

    left, right: uint8 grey or RGB images of the camera model's size, as the cameras gave them.
    [z_min_m, z_max_m]: depths (m) to search and keep. params: None = StereoParams().
    """
    params = params or StereoParams()
    check_pair(left, right)
    grey_left, grey_right = rectify_pair(rect, grey_image(left, "left"), grey_image(right, "right"))
    min_disparity, num_disparities = disparity_window(
        z_min_m, z_max_m, rect.focal_px, rect.baseline_m
    )
    disparity = disparity_image(grey_left, grey_right, min_disparity, num_disparities, params)
    return reproject(rect, disparity, left, z_min_m, z_max_m, params.subsample_step_px)


def to_open3d(cloud: StereoCloud):
    """An open3d.geometry.PointCloud with colours in [0, 1] (Open3D imported only when asked)."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(cloud.points_C)))
    pcd.colors = o3d.utility.Vector3dVector(cloud.colors / 255.0)
    return pcd


def view_cloud(
    rect: Rectification,
    left: np.ndarray,
    right: np.ndarray,
    X_WC: np.ndarray,
    p_W_centre: np.ndarray,
    radius_m: float,
    params: StereoParams,
) -> StereoCloud:
    """The cloud of one capture of an object within radius_m of p_W_centre, taken with the left
    camera at X_WC: only the depths the object can occupy are searched and kept."""
    distance = float(np.linalg.norm(np.asarray(p_W_centre, float) - X_WC[:3, 3]))
    z_min, z_max = object_depth_window(distance, radius_m)
    return stereo_cloud(rect, left, right, z_min, z_max, params)


def depth_image(rect: Rectification, cloud: StereoCloud) -> DepthImage:
    """The cloud's rectified depth on the rectified left grid (for TSDF fusion): its frame D is
    the rectified left camera, X_CD = [R1^T, 0]."""
    w, h = rect.image_size
    depth = np.zeros((h, w), np.float32)
    p_rect = cloud.points_C @ rect.R1.T
    u, v = cloud.pixels_rect[:, 0].astype(int), cloud.pixels_rect[:, 1].astype(int)
    depth[v, u] = p_rect[:, 2]
    X_CD = np.eye(4)
    X_CD[:3, :3] = rect.R1.T
    return DepthImage(depth, rect.P1[:3, :3], X_CD)

"""Stereo pair -> disparity (OpenCV StereoSGBM) -> metric point cloud in the left optical frame C.

Disparity is left-referenced and in pixels: a left pixel (u, v) of the rectified pair matches the
right pixel (u - d, v). Depth in the rectified left frame is Z = f b / d, so a depth window
[z_min, z_max] fixes the SGBM search range (`disparity_window`), never a constant.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.disparity_filters import jump_mask, left_right_mask, texture_mask
from reconstruction.errors import ScannerError
from reconstruction.rectification import Rectification, rectify_pair
from reconstruction.stereo_params import (
    SGBM_MODES,
    SGBM_SCALE,
    StereoParams,
    disparity_window,
    object_depth_window,
    stereo_params,
)

__all__ = [
    "SGBM_MODES",
    "StereoCloud",
    "StereoParams",
    "compute_disparity",
    "disparity_image",
    "disparity_window",
    "object_depth_window",
    "points_from_disparity",
    "reproject",
    "stereo_cloud",
    "stereo_params",
    "to_open3d",
]


def _check_image(image: np.ndarray, name: str) -> None:
    if not isinstance(image, np.ndarray):
        raise ScannerError(f"{name} image: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ScannerError(f"{name} image: expected 8-bit pixels (uint8), got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))):
        channels = image.shape[2] if image.ndim == 3 else f"{image.ndim} dimensions"
        raise ScannerError(
            f"{name} image: expected grey (H, W) or RGB (H, W, 3), got shape {image.shape} "
            f"({channels} channels)"
        )
    if min(image.shape[:2]) < 1:
        raise ScannerError(f"{name} image: empty ({image.shape})")


def _grey(image: np.ndarray, name: str) -> np.ndarray:
    """RGB (the simulator's and our capture files' channel order) or grey -> grey."""
    _check_image(image, name)
    if image.ndim == 2:
        return image
    if image.shape[2] == 1:
        return image[..., 0]
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def check_pair(left: np.ndarray, right: np.ndarray) -> None:
    """Both images uint8 grey or RGB, of the same size; a ScannerError naming the problem."""
    _check_image(left, "left")
    _check_image(right, "right")
    if left.shape[:2] != right.shape[:2]:
        raise ScannerError(
            f"stereo pair: left image is {left.shape[1]}x{left.shape[0]} but right image is "
            f"{right.shape[1]}x{right.shape[0]}"
        )


def _sgbm(left, right, min_disparity, num_disparities, params: StereoParams) -> np.ndarray:
    """Raw SGBM in pixels, NaN where SGBM found nothing.

    Left columns below min_disparity can only match outside the right image and right columns
    beyond width - min_disparity only left pixels outside the left image, so both are cropped
    before matching (about 20 % less work at the working distance); the result is the same.
    """
    height, width = left.shape
    shift = min(max(min_disparity, 0), width - 1)
    channels = 1
    p1, p2 = params.penalties(channels)
    matcher = cv2.StereoSGBM_create(
        minDisparity=min_disparity - shift,
        numDisparities=num_disparities,
        blockSize=params.block_size_px,
        P1=p1,
        P2=p2,
        disp12MaxDiff=params.disp12_max_diff_px,
        uniquenessRatio=params.uniqueness_ratio_percent,
        speckleWindowSize=params.speckle_window_px,
        speckleRange=params.speckle_range_px,
        mode=SGBM_MODES[params.mode],
    )
    raw = matcher.compute(left[:, shift:], right[:, : width - shift])
    disparity = np.full((height, width), np.nan, np.float32)
    found = raw >= (min_disparity - shift) * SGBM_SCALE
    disparity[:, shift:][found] = raw[found].astype(np.float32) / SGBM_SCALE + shift
    return disparity


def compute_disparity(
    left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int, **params
) -> np.ndarray:
    """Left-referenced disparity (float32 pixels, NaN = invalid) of a RECTIFIED pair.

    left, right: uint8 grey (H, W) or RGB (H, W, 3). params: StereoParams fields by name.
    """
    return disparity_image(left, right, min_disparity, num_disparities, stereo_params(**params))


def disparity_image(
    left: np.ndarray,
    right: np.ndarray,
    min_disparity: int,
    num_disparities: int,
    params: StereoParams,
) -> np.ndarray:
    """compute_disparity with a StereoParams record."""
    check_pair(left, right)
    if not (isinstance(num_disparities, int | np.integer) and num_disparities > 0):
        raise ScannerError(f"num_disparities: must be a positive integer, got {num_disparities}")
    if num_disparities % SGBM_SCALE:
        raise ScannerError(f"num_disparities: must be a multiple of 16, got {num_disparities}")
    width = left.shape[1]
    # OpenCV needs a full search plus half a block inside the (cropped) image, else it fails.
    if width - max(int(min_disparity), 0) < num_disparities + params.block_size_px:
        raise ScannerError(
            f"disparity search {min_disparity}..{min_disparity + num_disparities} px does not fit "
            f"a {width} px wide image: no pixel could be matched (use a farther depth window)"
        )
    grey_left, grey_right = _grey(left, "left"), _grey(right, "right")
    disparity = _sgbm(grey_left, grey_right, int(min_disparity), num_disparities, params)
    keep = np.isfinite(disparity)
    if params.lr_check_max_diff_px is not None:
        # Right-referenced disparity: mirror both images and swap them.
        mirrored = _sgbm(
            grey_right[:, ::-1].copy(),
            grey_left[:, ::-1].copy(),
            int(min_disparity),
            num_disparities,
            params,
        )[:, ::-1]
        keep &= left_right_mask(disparity, mirrored, params.lr_check_max_diff_px)
    if params.texture_min_std_levels > 0:
        keep &= texture_mask(grey_left, params.texture_window_px, params.texture_min_std_levels)
    disparity[~keep] = np.nan
    if params.max_jump_px > 0:
        disparity[~jump_mask(disparity, params.jump_window_px, params.max_jump_px)] = np.nan
    return disparity


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
    grey_left, grey_right = rectify_pair(rect, _grey(left, "left"), _grey(right, "right"))
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

"""The reconstruction's input per view: a cloud in the camera frame, the flange pose, a depth map.

The stereo module produces these from a capture: points reprojected from the disparity, then
expressed in the ORIGINAL left optical frame C (not the rectified one), so that X_WC = X_WF @ X_FC
applies directly. The depth map may stay on the rectified grid: `DepthImage.X_CD` says where its
optical frame D is (for the rectified left camera, X_CD = [R1^T, 0]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import check_pose


@dataclass(frozen=True, eq=False)
class DepthImage:
    """Depth (H, W) float32 in metres along the optical axis of frame D (0 or NaN = no data),
    pinhole intrinsics K (pixels) of that image, and the pose X_CD of its frame in C."""

    depth_m: np.ndarray
    K: np.ndarray
    X_CD: np.ndarray = field(default_factory=lambda: np.eye(4))
    color: np.ndarray | None = None  # (H, W, 3) uint8 on the same grid, optional

    def __post_init__(self) -> None:
        depth = np.asarray(self.depth_m, np.float32)
        if depth.ndim != 2:
            raise ScannerError(f"depth image: expected (H, W), got {depth.shape}")
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0).astype(np.float32)
        K = np.asarray(self.K, float)
        if K.shape != (3, 3) or not K[0, 0] > 0 or not K[1, 1] > 0:
            raise ScannerError("depth image: K must be a 3x3 intrinsic matrix")
        if self.color is not None and np.asarray(self.color).shape != (*depth.shape, 3):
            raise ScannerError("depth image: color must be (H, W, 3) on the depth grid")
        object.__setattr__(self, "depth_m", depth)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "X_CD", check_pose(self.X_CD, "depth image X_CD"))
        for a in (self.depth_m, self.K, self.X_CD):
            a.setflags(write=False)


@dataclass(frozen=True, eq=False)
class ViewCloud:
    """One view: points (N, 3) in the left optical frame C (metres), colours (N, 3) uint8, the
    measured flange pose X_WF (4x4), optionally its depth map for TSDF fusion, and when it
    was captured."""

    index: int
    points_C: np.ndarray
    colors: np.ndarray
    X_WF: np.ndarray
    depth: DepthImage | None = None
    # When the capture was taken (s, the capture's stamp): the order views arrive in, which
    # pairwise registration follows (NaN: unknown, the list order counts).
    stamp_s: float = math.nan

    def __post_init__(self) -> None:
        points = np.asarray(self.points_C, np.float64)
        colors = np.asarray(self.colors)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ScannerError(f"view {self.index}: points_C must be (N, 3), got {points.shape}")
        if colors.shape != points.shape:
            raise ScannerError(
                f"view {self.index}: colors must be (N, 3) like the points, got {colors.shape}"
            )
        object.__setattr__(self, "points_C", points)
        object.__setattr__(self, "colors", colors.astype(np.uint8))
        object.__setattr__(self, "X_WF", check_pose(self.X_WF, f"view {self.index}: X_WF"))
        for a in (self.points_C, self.colors, self.X_WF):
            a.setflags(write=False)

"""The table an object stands on, found in the data and removed.

Without a cell model nothing says where the table is; it is the plane that carries the object:
a large plane with every camera on one side and what is not on it on that side as well. The
second condition tells the table from a wall of the object: the cameras see a front wall from
its outside too, but the rest of the object lies behind it, away from the cameras.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from reconstruction.common.checks import check_fields, fraction, integer, positive


@dataclass(frozen=True)
class TableConfig:
    # RANSAC inlier distance: a few times the stereo noise of a flat, textured table at 0.5-0.7 m.
    distance_m: float = positive(0.002)
    # Points closer to the plane than this (on the cameras' side) go with it: the table's own
    # noise and the shadowed rim where the object meets it.
    clearance_m: float = positive(0.003)
    # A table holds at least this share of the points (else there is none in the data).
    min_share: float = fraction(0.1)
    # The share of off-plane points that must lie on the cameras' side of a table.
    min_above_share: float = fraction(0.9)
    # Planes tried, largest first.
    planes: int = integer(4)
    seed: int = 0

    def __post_init__(self) -> None:
        check_fields("table", self)


@dataclass(frozen=True, eq=False)
class TablePlane:
    """n . p = d with unit normal n pointing to the cameras' side (metres), the share of the
    points it holds."""

    normal_W: np.ndarray
    offset_m: float
    share: float

    def height_m(self, p_W: np.ndarray) -> np.ndarray:
        """Signed distance above the table (towards the cameras) of points (N, 3)."""
        return np.asarray(p_W, float) @ self.normal_W - self.offset_m


def find_table(
    p_W: np.ndarray, camera_centres_W: Sequence[np.ndarray], config: TableConfig = TableConfig()
) -> TablePlane | None:
    """The table in points (N, 3) in W, or None when no plane carries the rest."""
    points = np.asarray(p_W, float)
    cameras = np.asarray(camera_centres_W, float).reshape(-1, 3)
    if len(points) < 3 or len(cameras) == 0:
        return None
    o3d.utility.random.seed(config.seed)  # RANSAC's samples: the same table run to run
    left = np.arange(len(points))
    for _ in range(config.planes):
        if len(left) < max(3, config.min_share * len(points)):
            return None
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[left]))
        (a, b, c, d), inliers = cloud.segment_plane(config.distance_m, 3, 1000)
        n = np.array([a, b, c], float)
        scale = np.linalg.norm(n)
        n, offset = n / scale, -d / scale
        share = len(inliers) / len(points)
        if share < config.min_share:
            return None
        side = cameras @ n - offset
        if np.all(side > 0) or np.all(side < 0):
            if side[0] < 0:
                n, offset = -n, -offset
            plane = TablePlane(n, float(offset), share)
            height = plane.height_m(points)
            off = np.abs(height) > config.clearance_m
            if not off.any() or np.mean(height[off] > 0) >= config.min_above_share:
                return plane
        left = np.delete(left, inliers)
    return None


def above_table(p_W: np.ndarray, table: TablePlane, clearance_m: float) -> np.ndarray:
    """Keep mask (N,): the points higher than `clearance_m` above the table."""
    return table.height_m(p_W) > clearance_m

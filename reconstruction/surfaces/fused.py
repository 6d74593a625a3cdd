"""The fused cloud: every view's points in the world frame W, voxel-averaged, with its local
planes' normals; and its file."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import rotate_vectors, transform_points
from reconstruction.common.voxels import voxel_means
from reconstruction.registration.filtering import (
    FilteredCloud,
    o3d_cloud,
)
from reconstruction.surfaces.normals import local_planes, off_surface


@dataclass(frozen=True, eq=False)
class FusedCloud:
    """All views' points in W (N, 3), colours uint8, unit normals facing the cameras."""

    points_W: np.ndarray
    colors: np.ndarray
    normals_W: np.ndarray

    def __len__(self) -> int:
        return len(self.points_W)


def fuse_clouds(
    clouds: Sequence[FilteredCloud], X_WC: Sequence[np.ndarray], voxel_size_m: float
) -> FusedCloud:
    """Every view moved to W by its X_WC, merged, and voxel-averaged (normals re-normalised;
    the cells in the order of `voxel_means`)."""
    if not len(clouds):
        return FusedCloud(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros((0, 3)))
    points = np.vstack([transform_points(X, c.points_C) for c, X in zip(clouds, X_WC)])
    normals = np.vstack([rotate_vectors(X, c.normals_C) for c, X in zip(clouds, X_WC)])
    # Colours averaged as Open3D averaged them (0-1), so that they round alike.
    colors = np.vstack([c.colors for c in clouds]) / 255.0
    points, normals, colors = voxel_means(points, voxel_size_m, normals, colors)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return FusedCloud(points, np.clip(np.round(colors * 255), 0, 255).astype(np.uint8), normals)


def refine_fused(fused: FusedCloud, radius_m: float, outlier_sigmas: float) -> FusedCloud:
    """The fused cloud with its local planes' normals, without the points far off them."""
    if radius_m <= 0 or len(fused) == 0:
        return fused
    planes = local_planes(fused.points_W, fused.normals_W, radius_m)
    keep = ~off_surface(planes.residuals_m, outlier_sigmas)
    return FusedCloud(fused.points_W[keep], fused.colors[keep], planes.normals[keep])


def save_cloud(fused: FusedCloud, path: Path) -> None:
    """PLY with normals and colours, metres in W."""
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise ScannerError(f"{path}: the fused cloud is written as .ply")
    cloud = o3d_cloud(fused.points_W, fused.normals_W, fused.colors)
    if not o3d.io.write_point_cloud(str(path), cloud):
        raise ScannerError(f"{path}: could not write the cloud")

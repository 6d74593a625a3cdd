"""A surface by method name (poisson, poisson_closed, tsdf, rbf, ball_pivoting): the dispatch,
and the methods that are thin adapters of a library or of the RBF fit."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from reconstruction.common.errors import ScannerError
from reconstruction.registration.filtering import (
    RegionOfInterest,
    RemovePoints,
    o3d_cloud,
)
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.fused import FusedCloud
from reconstruction.surfaces.meshes import (
    DepthView,
    SurfaceInput,
    SurfaceMesh,
    finish_mesh,
)
from reconstruction.surfaces.poisson import poisson_closed_mesh, poisson_mesh
from reconstruction.surfaces.rbf import RbfParams, rbf_surface
from reconstruction.surfaces.topology import (
    canonical_order,
)
from reconstruction.surfaces.tsdf import tsdf_mesh


def ball_pivoting_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    fused = inputs.fused
    pc = o3d_cloud(fused.points_W, fused.normals_W, fused.colors)
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pc, o3d.utility.DoubleVector(list(config.ball_pivoting_radii_m))
    )
    return finish_mesh("ball_pivoting", mesh, config)


def rbf_params(config: SurfaceConfig) -> RbfParams:
    """The RBF surface's settings (`surfaces.rbf_*`)."""
    return RbfParams(
        centre_spacing_m=config.rbf_centre_spacing_m,
        max_centres=config.rbf_max_centres,
        offset_m=config.rbf_offset_m,
        kernel=config.rbf_kernel,
        neighbors=config.rbf_neighbors,
        smoothing=config.rbf_smoothing,
        voxel_size_m=config.rbf_voxel_size_m,
        max_distance_m=config.rbf_max_distance_m,
    )


def rbf_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """The RBF implicit surface of the fused cloud where the data are, coloured by the
    nearest fused point."""
    fused = inputs.fused
    surface = rbf_surface(fused.points_W, fused.normals_W, rbf_params(config))
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(surface.vertices),
        o3d.utility.Vector3iVector(surface.triangles.astype(np.int32)),
    )
    if len(surface.vertices):
        _, nearest = cKDTree(fused.points_W).query(surface.vertices)
        mesh.vertex_colors = o3d.utility.Vector3dVector(fused.colors[nearest] / 255.0)
    return finish_mesh("rbf", canonical_order(mesh), config)


# One entry per name in SURFACE_METHOD_NAMES (the configuration checks names without importing
# the methods; a test holds the two equal).
SURFACE_METHODS: dict[str, Callable[[SurfaceInput, SurfaceConfig], SurfaceMesh]] = {
    "poisson": poisson_mesh,
    "poisson_closed": poisson_closed_mesh,
    "tsdf": tsdf_mesh,
    "ball_pivoting": ball_pivoting_mesh,
    "rbf": rbf_mesh,
}


def build_surface(
    method: str,
    fused: FusedCloud,
    config: SurfaceConfig,
    depth_views: Sequence[DepthView] = (),
    roi: RegionOfInterest | None = None,
    remove_points: RemovePoints | None = None,
) -> SurfaceMesh:
    inputs = SurfaceInput(fused, depth_views, roi or RegionOfInterest(shape="none"), remove_points)
    return surface_from(method, inputs, config)


def surface_from(method: str, inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """One surface from inputs that several methods may share (one Poisson solve)."""
    if method not in SURFACE_METHODS:
        raise ScannerError(
            f"unknown surface method '{method}'; valid: {', '.join(SURFACE_METHODS)}"
        )
    return SURFACE_METHODS[method](inputs, config)

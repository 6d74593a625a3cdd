"""Triangle meshes in the world frame W (metres): the record every surface method returns, what
it is built from (SurfaceInput), the cleaning and hole filling every mesh gets, and its files."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d

from reconstruction.common.errors import ScannerError
from reconstruction.registration.filtering import (
    RegionOfInterest,
    RemovePoints,
)
from reconstruction.registration.views import DepthImage
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.fused import FusedCloud
from reconstruction.surfaces.topology import (
    clean_mesh,
    fill_small_holes,
)

MESH_SUFFIXES = (".ply", ".obj", ".stl")


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """A triangle mesh in W: vertices (V, 3) m, triangles (M, 3), vertex colours (V, 3) uint8
    or None."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray | None = None
    filled_holes: int = 0  # small holes closed by `finish_mesh` (filled, not seen)
    filled_area_m2: float = 0.0  # their area

    def to_open3d(self) -> o3d.geometry.TriangleMesh:
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.array(self.vertices, np.float64)),
            o3d.utility.Vector3iVector(np.array(self.triangles, np.int32)),
        )
        if self.colors is not None:
            mesh.vertex_colors = o3d.utility.Vector3dVector(np.array(self.colors) / 255.0)
        return mesh


@dataclass(frozen=True, eq=False)
class DepthView:
    """A depth map with the camera pose to integrate it at."""

    depth: DepthImage
    X_WC: np.ndarray
    index: int


def _from_open3d(
    name: str, mesh: o3d.geometry.TriangleMesh, filled_holes: int, filled_area_m2: float
) -> SurfaceMesh:
    colors = (
        np.clip(np.round(np.asarray(mesh.vertex_colors) * 255), 0, 255).astype(np.uint8)
        if mesh.has_vertex_colors()
        else None
    )
    return SurfaceMesh(
        name,
        np.asarray(mesh.vertices).copy(),
        np.asarray(mesh.triangles).copy(),
        colors,
        filled_holes,
        filled_area_m2,
    )


def finish_mesh(name: str, mesh: o3d.geometry.TriangleMesh, config: SurfaceConfig) -> SurfaceMesh:
    """Clean the mesh and close its small holes; the count of closed holes goes with it."""
    clean_mesh(mesh, config.min_component_fraction)
    area = mesh.get_surface_area()
    filled = fill_small_holes(mesh, config.fill_holes_max_radius_m)
    return _from_open3d(name, mesh, filled, max(mesh.get_surface_area() - area, 0.0))


@dataclass(frozen=True, eq=False)
class SurfaceInput:
    """What a surface is built from: the fused cloud in W, the depth maps at their poses (TSDF),
    and the region of interest and the caller's point filter (applied to the depth maps as they
    were to the clouds)."""

    fused: FusedCloud
    depth_views: Sequence[DepthView] = ()
    roi: RegionOfInterest = RegionOfInterest(shape="none")
    remove_points: RemovePoints | None = None
    # One Poisson solve serves both "poisson" and "poisson_closed" (they may run in parallel).
    shared: dict = field(default_factory=dict, compare=False)
    lock: threading.Lock = field(default_factory=threading.Lock, compare=False)


def save_mesh(mesh: SurfaceMesh, path: Path) -> None:
    """PLY, OBJ or STL by suffix, metres in W."""
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ScannerError(f"{path}: mesh output must be one of {', '.join(MESH_SUFFIXES)}")
    m = mesh.to_open3d()
    m.compute_triangle_normals()
    m.compute_vertex_normals()
    if path.suffix.lower() == ".stl":
        m.vertex_colors = o3d.utility.Vector3dVector()
    if not o3d.io.write_triangle_mesh(str(path), m, write_ascii=False):
        raise ScannerError(f"{path}: could not write the mesh")

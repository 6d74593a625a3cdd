"""Screened Poisson meshes of the fused cloud (solved in a process of its own).

Poisson closes every surface, including the unseen side of the object (the RX60 sees ~10 % of
the viewing sphere), so its mesh is trimmed twice: vertices of low Poisson density (few samples
nearby, the usual criterion) and vertices farther than `poisson_max_distance_m` from any fused
point (what density alone misses when the extrapolated cap is large); the closed variant keeps
the whole closed surface."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from reconstruction.common.errors import ScannerError
from reconstruction.common.kdtree import query_workers
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.meshes import SurfaceInput, SurfaceMesh, finish_mesh
from reconstruction.surfaces.poisson_solver import solve_poisson_apart
from reconstruction.surfaces.topology import (
    triangle_components,
)


def _poisson_solution(inputs: SurfaceInput, config: SurfaceConfig):
    """The untrimmed Poisson surface and its densities, solved once per input."""
    with inputs.lock:
        if "poisson" not in inputs.shared:
            fused = inputs.fused
            if len(fused) < 100:
                raise ScannerError(f"Poisson: only {len(fused)} fused points, nothing to mesh")
            s = solve_poisson_apart(
                fused.points_W, fused.normals_W, fused.colors, config.poisson_depth
            )
            mesh = o3d.geometry.TriangleMesh(
                o3d.utility.Vector3dVector(s.vertices), o3d.utility.Vector3iVector(s.triangles)
            )
            if len(s.colors):
                mesh.vertex_colors = o3d.utility.Vector3dVector(s.colors)
            inputs.shared["poisson"] = (mesh, s.density)
        mesh, density = inputs.shared["poisson"]
    return o3d.geometry.TriangleMesh(mesh), density


def _unsupported(inputs: SurfaceInput, mesh, config: SurfaceConfig) -> np.ndarray:
    """Vertices farther than poisson_max_distance_m from every fused point."""
    vertices = np.asarray(mesh.vertices)
    far, _ = cKDTree(inputs.fused.points_W).query(
        vertices,
        distance_upper_bound=config.poisson_max_distance_m,
        workers=query_workers(len(vertices)),
    )
    return ~np.isfinite(far)


def poisson_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """Poisson trimmed to the data: what was seen, open where nothing was."""
    mesh, density = _poisson_solution(inputs, config)
    drop = density < np.quantile(density, config.poisson_density_quantile)
    mesh.remove_vertices_by_mask(drop | _unsupported(inputs, mesh, config))
    return finish_mesh("poisson", mesh, config)


def poisson_closed_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """Poisson untrimmed, its main component: closed where the data surround the object (a
    collision model, a print), with the area it bridges beyond the data as `filled_area_m2`."""
    mesh, _ = _poisson_solution(inputs, config)
    clusters, counts = triangle_components(np.asarray(mesh.triangles))
    mesh.remove_triangles_by_mask(clusters != int(np.argmax(counts)))
    mesh.remove_unreferenced_vertices()
    out = finish_mesh("poisson_closed", mesh, config)
    unsupported = _unsupported(inputs, mesh, config)
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    bridged = unsupported[t].all(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
    return replace(out, filled_area_m2=out.filled_area_m2 + float(area[bridged].sum()))

"""A small hole whose rim is pinched (two fans of the surface meet at a rim vertex) cannot be
patched without reusing an edge; it is reopened one ring wider and closed there. The patch is
cut from a two-hanging scan's closed Poisson model (tests/data/pinched_hole.npz, 6 mm around
the hole, metres)."""

from pathlib import Path

import numpy as np
import open3d as o3d

from reconstruction.surfaces.topology import _small_loops, fill_small_holes, mesh_quality

PATCH = Path(__file__).parent / "data" / "pinched_hole.npz"


def _patch() -> o3d.geometry.TriangleMesh:
    data = np.load(PATCH)
    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(data["vertices"]), o3d.utility.Vector3iVector(data["triangles"])
    )


def test_the_pinched_hole_is_closed_and_the_patch_stays_manifold():
    mesh = _patch()
    vertices = np.asarray(mesh.vertices)
    before = mesh_quality(mesh)
    assert len(_small_loops(vertices, np.asarray(mesh.triangles), 0.001)) == 1
    assert not mesh.is_vertex_manifold()  # the pinch
    assert fill_small_holes(mesh, 0.001) == 1
    after = mesh_quality(mesh)
    assert not _small_loops(vertices, np.asarray(mesh.triangles), 0.002)
    assert after.non_manifold_edges == 0 and mesh.is_vertex_manifold()
    # Only the cut's outer rim stays open, as it was; the surface changed only at the hole.
    assert after.boundary_loops_m == before.boundary_loops_m[:1]
    assert abs(after.area_m2 - before.area_m2) < 1e-5  # 10 mm^2: a few cells


def test_a_pinched_hole_beyond_the_radius_is_left_alone():
    mesh = _patch()
    triangles = np.asarray(mesh.triangles).copy()
    assert fill_small_holes(mesh, 0.0001) == 0
    np.testing.assert_array_equal(np.asarray(mesh.triangles), triangles)

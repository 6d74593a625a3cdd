"""Surfaces from posed views: fused cloud, Poisson, TSDF, ball pivoting, cleaning, files.

"Watertight where the object is" made testable:
- where the whole object was seen (views all around it), the mesh is closed: one component, no
  boundary edge, no non-manifold edge, and it lies on the true surface;
- where only a band was seen (the RX60's case), the mesh covers the observed part of the true
  surface, and the only long boundary is the rim of that part: any other hole is small.
Views are exact poses here (registration is tested elsewhere); the object is a 0.1 m pebble so
that meshing takes about a second.
"""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
from synthetic_views import (
    OBJECT_CENTER_W,
    ROBOT_SIDE,
    cap_directions,
    make_scan,
    sphere_directions,
)

from reconstruction.common.errors import ScannerError
from reconstruction.evaluation.metrics import TriangleSurface, evaluate_surface
from reconstruction.registration.filtering import FilterConfig, RegionOfInterest, filter_view
from reconstruction.surfaces.build import build_surface
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.fused import fuse_clouds, save_cloud
from reconstruction.surfaces.meshes import DepthView, SurfaceMesh, save_mesh
from reconstruction.surfaces.topology import mesh_quality

ROI = RegionOfInterest(center_m=tuple(OBJECT_CENTER_W), radius_m=0.1)
SIZE_M = 0.1


def _posed(directions):
    scan = make_scan("pebble", SIZE_M, directions=directions, radius_m=0.3)
    clouds = [
        filter_view(v.index, v.points_C, v.colors, X, FilterConfig(roi=ROI))
        for v, X in zip(scan.views, scan.X_WC_true)
    ]
    fused = fuse_clouds(clouds, scan.X_WC_true, SurfaceConfig().fused_voxel_size_m)
    depth = [DepthView(v.depth, X, v.index) for v, X in zip(scan.views, scan.X_WC_true)]
    return scan, fused, depth


@pytest.fixture(scope="module")
def all_around():
    return _posed(sphere_directions(16))


@pytest.fixture(scope="module")
def band():
    return _posed(cap_directions(10, ROBOT_SIDE, math.radians(35.0)))


def _metrics(scan, mesh: SurfaceMesh) -> dict:
    return evaluate_surface(
        None,
        TriangleSurface(scan.vertices_W, scan.triangles),
        result_mesh=TriangleSurface(mesh.vertices, mesh.triangles),
        camera_centres_W=[X[:3, 3] for X in scan.X_WC_true],
        n_samples=30_000,
    )


def test_fused_cloud_has_unit_normals_facing_the_cameras(all_around):
    scan, fused, _ = all_around
    assert np.allclose(np.linalg.norm(fused.normals_W, axis=1), 1.0)
    # Outward normals: pointing away from the object's centre for (almost) every point of a
    # star-shaped blob.
    outward = np.einsum("ij,ij->i", fused.normals_W, fused.points_W - OBJECT_CENTER_W) > 0
    assert outward.mean() > 0.99
    assert fused.colors.dtype == np.uint8 and fused.colors.shape == fused.points_W.shape


@pytest.mark.parametrize("method", ["poisson", "tsdf"])
def test_fully_seen_object_gives_a_closed_mesh_on_the_surface(all_around, method):
    scan, fused, depth = all_around
    mesh = build_surface(method, fused, SurfaceConfig(), depth, ROI)
    q = mesh_quality(mesh)
    assert q.n_components == 1
    assert q.boundary_edges == 0 and q.non_manifold_edges == 0 and q.watertight
    m = _metrics(scan, mesh)
    assert m["completeness_2mm"] > 0.99
    # 0.3 mm depth noise, 1 mm voxels: the surface sits within a fraction of a millimetre.
    assert m["accuracy_p90_mm"] < 0.5


@pytest.mark.parametrize("method", ["poisson", "tsdf"])
def test_band_scan_covers_what_was_seen(band, method):
    scan, fused, depth = band
    mesh = build_surface(method, fused, SurfaceConfig(), depth, ROI)
    m = _metrics(scan, mesh)
    assert 0.3 < m["observed_fraction"] < 0.9  # a band, not the whole object
    assert m["completeness_observed_2mm"] > 0.95
    assert m["accuracy_p90_mm"] < 0.5
    if method == "poisson":
        # Poisson closes the unseen side; the distance trim removes it, leaving one rim.
        loops = mesh_quality(mesh).boundary_loops_m
        assert loops and all(p < 0.05 * loops[0] for p in loops[1:])


def test_ball_pivoting_is_available(band):
    scan, fused, _ = band
    cfg = SurfaceConfig(methods=("ball_pivoting",))
    mesh = build_surface("ball_pivoting", fused, cfg)
    assert _metrics(scan, mesh)["accuracy_p90_mm"] < 0.5


def test_tsdf_needs_depth_maps(band):
    _, fused, _ = band
    with pytest.raises(ScannerError, match="depth"):
        build_surface("tsdf", fused, SurfaceConfig(), [], ROI)


def test_cleaning_drops_debris_and_degenerate_faces():
    from reconstruction.surfaces.topology import clean_mesh

    big = o3d.geometry.TriangleMesh.create_sphere(0.05, 40)
    debris = o3d.geometry.TriangleMesh.create_tetrahedron(0.001).translate((0.2, 0, 0))
    mesh = big + debris
    v = np.asarray(mesh.vertices)
    t = np.vstack([np.asarray(mesh.triangles), [[0, 0, 1]]])  # one degenerate face
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    clean_mesh(mesh, 0.02)
    assert len(mesh.triangles) == len(big.triangles)
    assert np.asarray(mesh.vertices)[:, 0].max() < 0.06


def test_holes_below_the_data_resolution_are_closed_and_counted_larger_ones_kept():
    from reconstruction.surfaces.meshes import finish_mesh

    # A 0.1 m sphere with ~0.8 mm edges (fine like a Poisson mesh at depth 9), far from the
    # origin like every mesh in W. One missing triangle is a sub-millimetre artefact; a cap of
    # 25 mm across is a real opening (an unseen region, a hole in the part) and must stay.
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.05, 200).translate(OBJECT_CENTER_W)
    normals_z = np.asarray(sphere.vertices)[np.asarray(sphere.triangles)].mean(axis=1)[:, 2]
    cap = np.flatnonzero(normals_z > OBJECT_CENTER_W[2] + 0.0485)
    sphere.remove_triangles_by_index([len(sphere.triangles) // 3, *cap.tolist()])
    sphere.remove_unreferenced_vertices()
    before = mesh_quality(
        SurfaceMesh("s", np.asarray(sphere.vertices), np.asarray(sphere.triangles))
    )
    assert len(before.boundary_loops_m) == 2
    mesh = finish_mesh("poisson", sphere, SurfaceConfig())
    after = mesh_quality(mesh)
    assert mesh.filled_holes == 1
    assert len(after.boundary_loops_m) == 1
    assert after.boundary_loops_m[0] == pytest.approx(before.boundary_loops_m[0], rel=0.01)
    # The filled triangles close the gap in place: every vertex is where it was.
    assert np.abs(np.linalg.norm(mesh.vertices - OBJECT_CENTER_W, axis=1) - 0.05).max() < 1e-9


def test_a_filled_hole_that_would_make_the_mesh_non_manifold_stays_open():
    from reconstruction.surfaces.topology import _manifold_patches

    # Two existing triangles share edge (0, 1). Patch A (two added triangles) puts a third
    # triangle on that edge; patch B (one added triangle) touches nothing existing twice.
    triangles = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [1, 4, 5], [6, 7, 8]])
    added = np.array([False, False, True, True, True])
    assert _manifold_patches(triangles, added).tolist() == [True, True, False, False, True]


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
def test_meshes_are_written_in_metres(tmp_path, suffix):
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.05, 20).translate(OBJECT_CENTER_W)
    mesh = SurfaceMesh("poisson", np.asarray(sphere.vertices), np.asarray(sphere.triangles))
    path = tmp_path / f"mesh{suffix}"
    save_mesh(mesh, path)
    back = o3d.io.read_triangle_mesh(str(path))
    assert len(back.triangles) == len(mesh.triangles)
    np.testing.assert_allclose(back.get_center(), sphere.get_center(), atol=1e-5)
    with pytest.raises(ScannerError):
        save_mesh(mesh, tmp_path / "mesh.xyz")


def test_fused_cloud_is_written_as_ply(tmp_path, band):
    _, fused, _ = band
    save_cloud(fused, tmp_path / "cloud.ply")
    back = o3d.io.read_point_cloud(str(tmp_path / "cloud.ply"))
    assert len(back.points) == len(fused) and back.has_normals() and back.has_colors()


def test_the_configuration_knows_exactly_the_methods_that_exist():
    from reconstruction.surfaces.build import SURFACE_METHODS
    from reconstruction.surfaces.config import SURFACE_METHOD_NAMES, SurfaceConfig

    assert set(SURFACE_METHOD_NAMES) == set(SURFACE_METHODS)
    with pytest.raises(ScannerError, match="surfaces.methods: unknown marching"):
        SurfaceConfig(methods=("poisson", "marching"))

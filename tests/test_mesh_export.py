"""Mesh exports: millimetres and the object frame round-trip to the world-frame metres mesh,
the object frame is right-handed and follows the object, decimation keeps its triangle bound
and reports a Hausdorff distance no sampled distance exceeds, closed meshes stay closed, and
bad settings are one-line errors naming the field or flag."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, rotvec_to_matrix, transform_points
from reconstruction.evaluation.metrics import distances_to_mesh, sample_surface
from reconstruction.outputs import save_outputs
from reconstruction.pipeline import ReconstructionResult
from reconstruction.surfaces.export import (
    ExportedMesh,
    MeshExportConfig,
    export_record,
    from_export_coordinates,
    point_triangle_distances,
    prepare_exports,
    principal_frame,
)
from reconstruction.surfaces.fused import FusedCloud
from reconstruction.surfaces.meshes import SurfaceMesh
from reconstruction.surfaces.topology import mesh_quality
from scanner.configs.scan import load_scan_config
from scanner.reconstruct.command import ReconstructOptions, _mesh_export
from scanner.reconstruct.stages import load_processing_config

# Where the robot's world puts a scanned object (the brief's STL spans x 0.30-0.51 m,
# z 0.92-1.08 m): far from the origin, so a frame or unit slip cannot hide.
X_W_PLACED = make_pose(rotvec_to_matrix(np.array([0.3, -0.5, 0.9])), [0.41, 0.05, 1.0])


def _sphere(radius_m: float, resolution: int) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_sphere(radius_m, resolution=resolution)
    m.remove_duplicated_vertices()
    return m


def _lumpy(resolution: int = 30) -> SurfaceMesh:
    """A closed, asymmetric shape (an ellipsoid bent and tapered along x) placed in W."""
    m = _sphere(1.0, resolution)
    p = np.asarray(m.vertices) * [0.1, 0.06, 0.03]
    p[:, 1] += 4.0 * p[:, 0] ** 2  # bent: a non-zero third moment along y
    p[:, 1:] *= 1 + 4.0 * p[:, [0]]  # tapered: and along x
    p_W = transform_points(X_W_PLACED, p)
    return SurfaceMesh("poisson_closed", p_W, np.asarray(m.triangles).copy())


def _placed_sphere(resolution: int) -> SurfaceMesh:
    m = _sphere(0.1, resolution)  # 0.2 m across
    p_W = np.asarray(m.vertices) + X_W_PLACED[:3, 3]
    return SurfaceMesh("poisson_closed", p_W, np.asarray(m.triangles).copy())


def _result(meshes: dict[str, SurfaceMesh]) -> ReconstructionResult:
    points = np.vstack([m.vertices for m in meshes.values()])[:100]
    fused = FusedCloud(points, np.zeros((len(points), 3), np.uint8), np.tile([0, 0, 1.0], (100, 1)))
    return ReconstructionResult(
        views=(),
        edges=(),
        X_FC_nominal=np.eye(4),
        X_FC=np.eye(4),
        handeye=None,
        fused=fused,
        meshes=meshes,
        timings_s={},
        skipped_views=(),
        notes=(),
        clouds=(),
    )


def _read(path: Path) -> tuple[np.ndarray, np.ndarray]:
    m = o3d.io.read_triangle_mesh(str(path))
    # STL stores each triangle's corners apart; the same float32 corners merge exactly.
    m.remove_duplicated_vertices()
    return np.asarray(m.vertices), np.asarray(m.triangles)


def test_mm_object_frame_files_round_trip_to_world_metres(tmp_path):
    mesh = _lumpy()
    config = MeshExportConfig(units="mm", frame="object")
    exports = prepare_exports({"poisson_closed": mesh}, config, "poisson_closed")
    paths = save_outputs(_result({"poisson_closed": mesh}), tmp_path, (".ply", ".stl"), exports)
    assert {"mesh_poisson_closed_object_mm.ply", "mesh_poisson_closed_object_mm.stl"} <= set(paths)
    assert not (tmp_path / "mesh_poisson_closed.ply").exists()  # mm never under the metres name
    side = yaml.safe_load((tmp_path / "mesh_export.yaml").read_text())
    assert side["units"] == "mm" and side["frame"] == "object" and side["units_per_m"] == 1000
    X_WO = np.array(side["X_WO"])
    vertices, triangles = _read(tmp_path / "mesh_poisson_closed_object_mm.ply")
    np.testing.assert_array_equal(triangles, mesh.triangles)
    # In mm around the object's own centre: 100 mm half-length, not 0.4 m away.
    assert 90 < np.abs(vertices).max() < 120
    p_W = from_export_coordinates(vertices, X_WO, side["units"])
    scale = np.abs(mesh.vertices).max()
    np.testing.assert_allclose(p_W, mesh.vertices, rtol=0, atol=1e-9 * scale)
    # STL holds float32: 6e-5 mm at 100 mm, and it is still one closed surface.
    vertices, triangles = _read(tmp_path / "mesh_poisson_closed_object_mm.stl")
    assert mesh_quality(SurfaceMesh("stl", vertices, triangles)).watertight
    assert side["meshes"]["poisson_closed"]["watertight"] is True


def test_default_export_is_the_world_metres_mesh_under_its_old_name(tmp_path):
    mesh = _lumpy(12)
    save_outputs(_result({"poisson": mesh}), tmp_path)
    vertices, _ = _read(tmp_path / "mesh_poisson.ply")
    np.testing.assert_array_equal(vertices, mesh.vertices)
    side = yaml.safe_load((tmp_path / "mesh_export.yaml").read_text())
    np.testing.assert_array_equal(side["X_WO"], np.eye(4))
    assert side["units"] == "m" and side["decimate_triangles"] is None


def test_object_frame_is_right_handed_and_follows_the_object():
    mesh = _lumpy()
    X_WO = principal_frame(mesh.vertices, mesh.triangles)
    R = X_WO[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    # x along the 0.2 m length of the shape (rotated into W by X_W_PLACED); the bend tilts
    # the axis of largest spread by ~13 deg.
    assert abs(R[:, 0] @ X_W_PLACED[:3, 0]) > 0.95
    # Deterministic: the same surface listed in another order gives the same frame.
    rng = np.random.default_rng(1)
    order = rng.permutation(len(mesh.vertices))
    inverse = np.argsort(order)
    shuffled = inverse[mesh.triangles][rng.permutation(len(mesh.triangles))]
    X_again = principal_frame(mesh.vertices[order], shuffled[:, [1, 2, 0]])
    np.testing.assert_allclose(X_again, X_WO, atol=1e-12)
    # It follows the object: moving the object moves the frame with it (signs included).
    X_moved = make_pose(rotvec_to_matrix(np.array([-1.1, 0.4, 2.0])), [-0.2, 0.3, 0.5])
    X_moved_O = principal_frame(transform_points(X_moved, mesh.vertices), mesh.triangles)
    np.testing.assert_allclose(X_moved_O, X_moved @ X_WO, atol=1e-9)


def test_point_triangle_distances_match_open3d():
    rng = np.random.default_rng(2)
    a, b, c = (rng.normal(size=(1, 3)) for _ in range(3))
    p = rng.normal(size=(2000, 3)) * 2
    mine = point_triangle_distances(p, *(np.repeat(x, len(p), axis=0) for x in (a, b, c)))
    surface = SurfaceMesh("t", np.vstack([a, b, c]), np.array([[0, 1, 2]]))
    np.testing.assert_allclose(mine, distances_to_mesh(p, surface), atol=1e-6)


@pytest.fixture(scope="module")
def decimated_sphere():
    full = _placed_sphere(100)  # 39,600 triangles, 0.2 m across
    exports = prepare_exports(
        {"poisson_closed": full}, MeshExportConfig(decimate_triangles=5000), "poisson_closed"
    )
    return full, exports


def test_decimation_bound_and_hausdorff_is_an_upper_bound(decimated_sphere):
    full, exports = decimated_sphere
    (e,) = exports.meshes
    assert len(e.mesh.triangles) <= 5000
    assert e.triangles_full == len(full.triangles)
    h = e.hausdorff
    found = 0.0
    for a, b in ((full, e.mesh), (e.mesh, full)):
        points = np.vstack([sample_surface(a, 200_000, seed=7).points, a.vertices])
        found = max(found, float(distances_to_mesh(points, b).max()))
    # Open3D's distances are float32 relative to the mesh centre: ~1e-8 m at 0.1 m.
    assert found <= h.bound_m + 1e-7
    # Smooth 0.2 m sphere, 5k triangles: a few tenths of a mm, and the bound is tight.
    assert h.bound_m < 0.5e-3
    assert h.bound_m - found < 0.05e-3


def test_closed_mesh_stays_watertight_after_decimation(decimated_sphere, tmp_path):
    full, exports = decimated_sphere
    (e,) = exports.meshes
    assert e.watertight_full and e.watertight
    save_outputs(_result({"poisson_closed": full}), tmp_path, (".stl",), exports)
    vertices, triangles = _read(tmp_path / "mesh_poisson_closed.stl")
    assert len(triangles) <= 5000
    assert mesh_quality(SurfaceMesh("stl", vertices, triangles)).watertight
    side = yaml.safe_load((tmp_path / "mesh_export.yaml").read_text())
    entry = side["meshes"]["poisson_closed"]
    assert entry["watertight"] is True and "note" not in entry
    assert entry["hausdorff_bound_m"] == e.hausdorff.bound_m


def test_a_decimation_that_opens_the_model_says_so():
    full, exports = _lumpy(8), None
    broken = ExportedMesh("poisson_closed", full, 500, True, False, None)
    exports = replace(prepare_exports({}, MeshExportConfig()), meshes=(broken,))
    entry = export_record(exports, {})["meshes"]["poisson_closed"]
    assert entry["watertight"] is False and "not a closed model" in entry["note"]


@pytest.mark.parametrize(
    "field, value, needle",
    [
        ("units", "cm", "mesh_export.units: 'cm' is not one of m, mm"),
        ("frame", "tool", "mesh_export.frame: 'tool' is not one of world, object"),
        ("decimate_triangles", 3, "mesh_export.decimate_triangles: expected an integer in [4,"),
        ("hausdorff_tolerance_m", 0.0, "mesh_export.hausdorff_tolerance_m: expected a positive"),
    ],
)
def test_bad_settings_name_the_field(field, value, needle, tmp_path):
    with pytest.raises(ScannerError, match=None) as e:
        MeshExportConfig(**{field: value})
    assert needle in str(e.value)
    path = tmp_path / "processing.yaml"
    path.write_text(yaml.safe_dump({"mesh_export": {field: value}}))
    with pytest.raises(ScannerError) as e:
        load_processing_config(path)
    assert f"processing.yaml: {needle}" in str(e.value)


@pytest.mark.parametrize(
    "option, value, message",
    [
        ("units", "inch", "--units: 'inch' is not one of m, mm"),
        ("frame", "W", "--frame: 'W' is not one of world, object"),
        ("decimate", 0, "--decimate: expected an integer in [4, 100000000], got 0"),
    ],
)
def test_bad_flags_are_one_line_errors_naming_the_flag(option, value, message):
    with pytest.raises(ScannerError) as e:
        _mesh_export(MeshExportConfig(), ReconstructOptions(**{option: value}))
    assert str(e.value) == message


@pytest.fixture(scope="module")
def tiny_scan_dir(tiny_scan) -> Path:
    return tiny_scan.scan_dir


def test_reconstruct_writes_mm_object_frame_decimated_meshes(tiny_scan_dir, tmp_path, capsys):
    from scanner.commands.main import main

    out = tmp_path / "rec"
    argv = ["reconstruct", str(tiny_scan_dir), "--out", str(out), "--formats", "ply,stl"]
    assert main([*argv, "--units", "mm", "--frame", "object", "--decimate", "3000"]) == 0
    side = yaml.safe_load((out / "mesh_export.yaml").read_text())
    report = json.loads((out / "report.json").read_text())
    assert report["mesh_export"] == side
    assert side["frame_reference_mesh"] == "poisson"
    X_WO = np.array(side["X_WO"])
    centre_W = np.array(load_scan_config(None).scan_center_m)
    for name, entry in side["meshes"].items():
        assert entry["files"] == [f"mesh_{name}_object_mm.ply", f"mesh_{name}_object_mm.stl"]
        vertices, triangles = _read(out / entry["files"][0])
        assert len(triangles) == entry["triangles"] <= 3000
        if entry["triangles_full"] > 3000:
            # A rough 5-view 320x240 mesh: its rims and debris move by mm when decimated.
            assert 0 < entry["hausdorff_found_m"] <= entry["hausdorff_bound_m"] < 0.05
        # Back in W the model sits where the object hangs (within its 0.2 m size).
        p_W = from_export_coordinates(vertices, X_WO, "mm")
        assert np.linalg.norm(p_W.mean(axis=0) - centre_W) < 0.1
        # The object frame is centred on the model: mm coordinates within its size.
        assert np.abs(vertices).max() < 200

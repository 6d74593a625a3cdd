"""The fixture never enters the model: the model-side guard on synthetic clouds (flat, elongated,
hung off the centre vertical, a second hanging's rod), and a simulated two-hanging scan of a flat
ellipsoid (the shape that left a strip of rod in its mesh) checked against the true rod lines."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from reconstruction.common.transforms import invert, make_pose, rotation_about, transform_points
from reconstruction.hangings.merge import in_own_frames
from reconstruction.surfaces.fixture import (
    FixtureLine,
    fixture_points,
    points_on_fixture,
    without_fixture,
)

RNG = np.random.default_rng(4)
CENTRE = np.array([0.4, 0.0, 1.0])
ROD_RADIUS_M = 0.004


def _ellipsoid(semi_axes, n: int = 60_000, centre=CENTRE) -> np.ndarray:
    d = RNG.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return centre + d * np.asarray(semi_axes)


def _rod(x: float, y: float, z0: float, z1: float, n: int = 3000, noise_m=0.002) -> np.ndarray:
    """Points on a rod's surface (stereo noise across it) from z0 up to z1."""
    phi = RNG.uniform(0, 2 * math.pi, n)
    r = ROD_RADIUS_M + RNG.normal(0, noise_m, n)
    return np.column_stack([x + r * np.cos(phi), y + r * np.sin(phi), RNG.uniform(z0, z1, n)])


def _line(p=CENTRE, u=(0.0, 0.0, 1.0)) -> FixtureLine:
    return FixtureLine(tuple(map(float, p)), tuple(map(float, u)), ROD_RADIUS_M)


@pytest.mark.parametrize(
    "semi_axes, offset_m",
    [
        ((0.1, 0.05, 0.025), (0.0, 0.0)),  # flat: the most rod in view
        ((0.1, 0.025, 0.025), (0.0, 0.0)),  # elongated
        ((0.1, 0.05, 0.025), (0.03, -0.02)),  # hung off the centre vertical
    ],
)
def test_the_guard_cuts_the_rod_strip_and_none_of_the_object(semi_axes, offset_m):
    centre = CENTRE + [*offset_m, 0.0]
    body = _ellipsoid(semi_axes, centre=centre)
    # The rod hangs on the cell's line (the vertical above the scan centre) down to the surface.
    top = body[np.hypot(body[:, 0] - CENTRE[0], body[:, 1] - CENTRE[1]) < 0.002][:, 2].max()
    rod = _rod(CENTRE[0], CENTRE[1], top, CENTRE[2] + 0.2)
    cut = fixture_points(np.vstack([body, rod]), _line())
    assert not cut[: len(body)].any()
    # All of the rod above the object's surface around it (within 36 mm of the line; off the
    # centre vertical the surface still rises beside the clamp) but the first 12 mm.
    near = np.hypot(body[:, 0] - CENTRE[0], body[:, 1] - CENTRE[1]) < 0.036
    assert cut[len(body) :][rod[:, 2] > body[near, 2].max() + 0.012].all()
    assert cut[len(body) :].mean() > 0.8


def test_the_guard_leaves_an_object_without_a_rod_alone():
    body = _ellipsoid((0.1, 0.1, 0.1))
    assert without_fixture(body, [_line()]).all()


def test_each_hangings_rod_is_cut_on_its_own_line_in_the_merged_frame():
    body = _ellipsoid((0.1, 0.05, 0.025))
    rod0 = _rod(CENTRE[0], CENTRE[1], CENTRE[2] + 0.025, CENTRE[2] + 0.2)
    # The second hanging: turned about the centre by 120 deg; its rod arrives along the
    # turned line (T: second hanging's frame -> the first's).
    R = rotation_about(np.array([1.0, 1.0, 0.0]) / math.sqrt(2), math.radians(120))
    T = make_pose(R, CENTRE - R @ CENTRE)
    body1 = transform_points(invert(T), body)  # the same object as the second hanging holds it
    top1 = body1[np.hypot(body1[:, 0] - CENTRE[0], body1[:, 1] - CENTRE[1]) < 0.002][:, 2].max()
    rod1 = transform_points(T, _rod(CENTRE[0], CENTRE[1], top1, CENTRE[2] + 0.2))
    points = np.vstack([body, rod0, rod1])
    lines = [_line(), _line().moved(T)]
    keep = without_fixture(points, lines)
    assert keep[: len(body)].all()
    far0 = rod0[:, 2] > CENTRE[2] + 0.04
    assert not keep[len(body) : len(body) + len(rod0)][far0].any()
    # Above the turned object's surface around its line, all of that rod is cut.
    u1 = np.asarray(lines[1].u_W)
    along1, along_body = (rod1 - CENTRE) @ u1, (body - CENTRE) @ u1
    across_body = np.linalg.norm(body - CENTRE - np.outer(along_body, u1), axis=1)
    surface_top = along_body[across_body < 0.036].max()
    assert not keep[len(body) + len(rod0) :][along1 > surface_top + 0.012].any()


def test_the_cell_filter_sees_each_view_in_its_own_hangings_frame():
    T = make_pose(rotation_about(np.array([0.0, 0.0, 1.0]), 1.0), [0.1, 0.0, 0.0])
    seen = {}

    def remove(p_W, index):
        seen[index] = p_W
        return np.ones(len(p_W), bool)

    p_own = np.array([[0.4, 0.0, 1.2]])
    hook = in_own_frames(remove, [np.eye(4), T], {3: 0, 7: 1})
    hook(transform_points(T, p_own), 7)
    hook(p_own, 3)
    np.testing.assert_allclose(seen[7], p_own, atol=1e-12)
    np.testing.assert_allclose(seen[3], p_own, atol=1e-12)


def rod_points(points_W: np.ndarray, truth_vertices_W: np.ndarray, X_WO_hangings) -> int:
    """Points within 10 mm of a hanging's true rod axis and above the object there, in the
    first hanging's frame (where `points_W` and the true surface are)."""
    X0 = np.asarray(X_WO_hangings[0])
    count = 0
    for X in X_WO_hangings:
        T = X0 @ invert(np.asarray(X))  # that hanging's frame -> the first's
        count += points_on_fixture(points_W, truth_vertices_W, _line().moved(T))
    return count


def test_points_on_the_fixture_are_counted_above_the_object_only():
    body = _ellipsoid((0.1, 0.05, 0.025))
    rod = _rod(CENTRE[0], CENTRE[1], CENTRE[2] + 0.025, CENTRE[2] + 0.2, noise_m=0.0)
    assert points_on_fixture(body, body, _line()) == 0
    assert points_on_fixture(rod, body, _line()) == int((rod[:, 2] > CENTRE[2] + 0.035).sum())


def test_a_flat_ellipsoid_scanned_in_two_hangings_has_no_rod_in_its_model(tmp_path: Path):
    import open3d as o3d
    import yaml

    from scanner.configs.scan import scan_config_from_dict, with_overrides
    from scanner.scan.run import run_scan
    from tests.tiny_scan import HALF_RESOLUTION, TINY_PROCESSING, TINY_SCAN

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution=40)
    sphere.vertices = o3d.utility.Vector3dVector(np.asarray(sphere.vertices) * [0.1, 0.05, 0.025])
    o3d.io.write_triangle_mesh(str(tmp_path / "flat.obj"), sphere)
    # The tiny scan's roadmap, view candidates and coarse Poisson surface (with the closed one
    # of the two hangings: each is checked for rods). At 320x240 the hand-eye fit finds no
    # overlapping views and the second hanging fails its 1 mm inlier RMS: 640x480 stays.
    surfaces = {**TINY_PROCESSING["reconstruction"]["surfaces"], "methods": ["poisson"]}
    processing = {**TINY_PROCESSING, "reconstruction": {"surfaces": surfaces}}
    tiny = {k: TINY_SCAN[k] for k in ("planner", "views")} | {"processing": processing}
    config = with_overrides(
        scan_config_from_dict(tiny, "tiny"),
        object_spec=str(tmp_path / "flat.obj"),
        views=10,
        seed=5,
        hangings=2,
    )
    config = replace(config, camera=HALF_RESOLUTION)
    result = run_scan(config, tmp_path / "scan")
    scan = result.scan_dir
    assert result.report["hangings"][1]["verified"]  # both hangings, each with its rod, merged
    # The report's own count (against the truth) agrees.
    assert result.report["fixture_points"] == 0
    truth = yaml.safe_load((scan / "truth.yaml").read_text())
    results = scan / "results"
    true_vertices = np.asarray(o3d.io.read_triangle_mesh(str(scan / "truth_mesh.ply")).vertices)
    fused = np.asarray(o3d.io.read_point_cloud(str(results / "fused_cloud.ply")).points)
    assert rod_points(fused, true_vertices, truth["X_WO_hangings"]) == 0
    meshes = sorted(results.glob("mesh_*.ply"))
    assert len(meshes) >= 2
    for mesh in meshes:
        vertices = np.asarray(o3d.io.read_triangle_mesh(str(mesh)).vertices)
        assert len(vertices) > 1000, mesh.name
        assert rod_points(vertices, true_vertices, truth["X_WO_hangings"]) == 0, mesh.name

"""Metrics on cases whose answer is known exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruction.common.transforms import make_pose, twist_to_pose
from reconstruction.evaluation.metrics import (
    TriangleSurface,
    distances_to_mesh,
    distances_to_points,
    evaluate_surface,
    fscore,
    handeye_error,
    sample_surface,
    surface_metrics,
    visible_mask,
)


def _grid(n: int = 60, spacing_m: float = 0.001) -> np.ndarray:
    u = np.arange(n) * spacing_m
    x, y = np.meshgrid(u, u)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def _square(size_m: float = 0.1) -> TriangleSurface:
    v = np.array([[0, 0, 0], [size_m, 0, 0], [size_m, size_m, 0], [0, size_m, 0]], float)
    return TriangleSurface(v, np.array([[0, 1, 2], [0, 2, 3]]))


def _sphere(radius_m: float = 0.05) -> TriangleSurface:
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(radius=radius_m, resolution=60)
    return TriangleSurface(np.asarray(m.vertices), np.asarray(m.triangles))


def test_identical_clouds_are_perfect():
    p = _grid()
    d = distances_to_points(p, p)
    m = surface_metrics(d, d)
    assert m["chamfer_mm"] == 0.0
    assert m["fscore_1mm"] == m["fscore_2mm"] == m["completeness_2mm"] == 1.0
    assert m["accuracy_p90_mm"] == 0.0


def test_known_shift_is_measured_exactly():
    # A plane grid shifted 1.5 mm along its normal: every nearest neighbour is the point
    # straight below, so every distance is exactly the shift.
    p = _grid()
    q = p + [0.0, 0.0, 0.0015]
    m = surface_metrics(distances_to_points(q, p), distances_to_points(p, q))
    assert m["chamfer_mm"] == pytest.approx(1.5, abs=1e-9)
    assert m["accuracy_p90_mm"] == pytest.approx(1.5, abs=1e-9)
    assert m["fscore_1mm"] == 0.0  # nothing within 1 mm
    assert m["fscore_2mm"] == 1.0  # everything within 2 mm
    assert m["completeness_2mm"] == 1.0


def test_point_to_mesh_distance_is_exact():
    square = _square()
    p = np.array([[0.05, 0.05, 0.002], [0.05, 0.05, -0.0007], [0.12, 0.05, 0.0]])
    # Above the face, below it, and 20 mm beyond an edge in the plane.
    np.testing.assert_allclose(distances_to_mesh(p, square), [0.002, 0.0007, 0.02], atol=1e-7)


def test_fscore_is_the_harmonic_mean():
    d_rt = np.array([0.0, 0.0, 0.005, 0.005])  # precision 1/2 at 1 mm
    d_tr = np.array([0.0, 0.005, 0.005, 0.005])  # recall 1/4 at 1 mm
    assert fscore(d_rt, d_tr, 0.001) == pytest.approx(2 * 0.5 * 0.25 / 0.75)


def test_sampling_is_uniform_by_area():
    # Two triangles of area ratio 1:3 (a split rectangle) get samples in that ratio.
    v = np.array([[0, 0, 0], [1, 0, 0], [4, 0, 0], [0, 1, 0], [1, 1, 0], [4, 1, 0]], float)
    t = np.array([[0, 1, 4], [1, 2, 5]])  # areas 0.5 and 1.5
    s = sample_surface(TriangleSurface(v, t), 40_000, seed=1)
    frac_left = np.mean(s.points[:, 0] < 1.0 - 1e-12 + s.points[:, 1] * 0)
    # Binomial std at n = 40000 is 0.002; 4 sigma.
    assert frac_left == pytest.approx(0.25, abs=0.01)
    assert np.allclose(np.abs(s.normals[:, 2]), 1.0)


def test_visible_fraction_of_a_sphere_from_far_away():
    # From a far camera, a sphere point is visible when its normal is within the incidence
    # limit of the viewing direction: a cap of area fraction (1 - cos(limit)) / 2.
    sphere = _sphere()
    s = sample_surface(sphere, 20_000, seed=2)
    limit = math.radians(80.0)
    seen = visible_mask(s, sphere, [np.array([0.0, 0.0, 1000.0])], limit)
    # 0.01: binomial noise (0.0035 at 20000 samples) plus the facets of the tessellated sphere.
    assert np.mean(seen) == pytest.approx((1 - math.cos(limit)) / 2, abs=0.01)
    # Two opposite cameras see disjoint caps: exactly the union of the single-camera masks.
    down = visible_mask(s, sphere, [np.array([0, 0, -1000.0])], limit)
    both = visible_mask(s, sphere, [np.array([0, 0, 1000.0]), np.array([0, 0, -1000.0])], limit)
    assert not (seen & down).any()
    np.testing.assert_array_equal(both, seen | down)


def _square_under_occluder(size_m: float, corner_m) -> tuple[TriangleSurface, TriangleSurface]:
    """The 0.1 m square, and it together with a smaller square (side size_m, lower corner at
    corner_m) above it."""
    big = _square(0.1)
    small = TriangleSurface(_square(size_m).vertices + corner_m, np.array([[0, 1, 2], [0, 2, 3]]))
    both = TriangleSurface(
        np.vstack([big.vertices, small.vertices]),
        np.vstack([big.triangles, small.triangles + 4]),
    )
    return big, both


def test_occluded_samples_are_not_visible():
    # A small square hides the part of the big one right behind it from a camera above.
    big, both = _square_under_occluder(0.02, [0.04, 0.04, 0.05])
    s = sample_surface(big, 5000, seed=3)
    seen = visible_mask(s, both, [np.array([0.05, 0.05, 1000.0])])
    behind = np.all((s.points[:, :2] > 0.0401) & (s.points[:, :2] < 0.0599), axis=1)
    assert not seen[behind].any()
    assert seen[~behind & np.all(np.abs(s.points[:, :2] - 0.05) > 0.011, axis=1)].all()


def test_a_stereo_view_sees_only_what_both_of_its_cameras_see():
    # The small square (0.1 m above) hides a patch of the big one from each eye; the patches
    # are 22 mm apart (eyes 0.2 m apart, 1 m above), so a stereo view misses both while either
    # eye alone misses one.
    big, both = _square_under_occluder(0.01, [0.045, 0.045, 0.1])
    s = sample_surface(big, 20_000, seed=4)
    left, right = np.array([-0.05, 0.05, 1.0]), np.array([0.15, 0.05, 1.0])
    seen_left = visible_mask(s, both, [left])
    seen_right = visible_mask(s, both, [right])
    stereo = visible_mask(s, both, [np.stack([left, right])])
    np.testing.assert_array_equal(stereo, seen_left & seen_right)
    assert (~seen_left).sum() > 0 and (~seen_right).sum() > 0
    assert not (~seen_left & ~seen_right).any()
    assert (~stereo).sum() == (~seen_left).sum() + (~seen_right).sum()
    # Two views, each a stereo pair: the union of what each pair sees.
    above = np.array([0.05, 0.05, 1.0])
    views = visible_mask(s, both, [np.stack([left, right]), above])
    np.testing.assert_array_equal(views, stereo | visible_mask(s, both, [above]))


def test_evaluate_surface_of_the_truth_itself_is_near_zero():
    sphere = _sphere()
    m = evaluate_surface(
        np.zeros((1, 3)),
        sphere,
        result_mesh=sphere,
        camera_centres_W=[np.array([0.0, 0.0, 1.0])],
        n_samples=20_000,
    )
    # float32 inside Open3D's distance query: ~1e-8 m at 0.05 m.
    assert m["chamfer_mm"] < 1e-3
    assert m["completeness_2mm"] == 1.0 and m["completeness_observed_2mm"] == 1.0
    assert 0.3 < m["observed_fraction"] < 0.5  # one camera 1 m away sees under half a sphere


def test_handeye_error_splits_translation_and_rotation():
    X = make_pose(np.eye(3), [0.0, 0.0, 0.08])
    X_err = X @ twist_to_pose([0.0, 0.0, math.radians(0.5), 0.003, 0.004, 0.0])
    e = handeye_error(X_err, X)
    assert e["handeye_error_mm"] == pytest.approx(5.0)
    assert e["handeye_error_deg"] == pytest.approx(0.5)

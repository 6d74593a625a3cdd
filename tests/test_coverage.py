"""The coverage estimate (no truth) against what is known about synthetic views."""

import numpy as np
import pytest

from reconstruction.evaluation.coverage import coverage_estimate
from reconstruction.surfaces.fused import FusedCloud


def _sphere_cloud(n: int, radius: float, keep) -> FusedCloud:
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[keep(d)]
    return FusedCloud(radius * d, np.zeros((len(d), 3), np.uint8), d)


def _cameras(directions: np.ndarray, distance: float) -> list[np.ndarray]:
    return list(distance * directions / np.linalg.norm(directions, axis=1, keepdims=True))


def test_an_object_seen_from_everywhere_is_covered():
    cloud = _sphere_cloud(40_000, 0.1, lambda d: np.ones(len(d), bool))
    rng = np.random.default_rng(1)
    coverage = coverage_estimate(cloud, _cameras(rng.normal(size=(40, 3)), 0.5))
    assert coverage.fraction > 0.97
    assert coverage.unseen_area_m2 < 0.03 * 4 * np.pi * 0.1**2


def test_an_object_seen_from_below_is_covered_as_far_as_the_cameras_see():
    # Cameras on a cap below (as a hung object is seen); the data are the surface they see.
    # The closed surface bridges the top, which no camera sees: the estimate must match the
    # share of the true surface the cameras see (the simulator's observed_fraction).
    import open3d as o3d

    from reconstruction.evaluation.metrics import TriangleSurface, sample_surface, visible_mask

    rng = np.random.default_rng(2)
    below = rng.normal(size=(400, 3))
    below = below[below[:, 2] < -0.8 * np.linalg.norm(below, axis=1)][:30]
    centres = _cameras(below, 0.5)
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.1, 80)
    truth = TriangleSurface(np.asarray(sphere.vertices), np.asarray(sphere.triangles))
    samples = sample_surface(truth, 60_000)
    seen = visible_mask(samples, truth, centres)
    assert 0.3 < seen.mean() < 0.9
    cloud = FusedCloud(
        samples.points[seen], np.zeros((seen.sum(), 3), np.uint8), samples.normals[seen]
    )
    coverage = coverage_estimate(cloud, centres)
    assert coverage.fraction == pytest.approx(seen.mean(), abs=0.05)
    # The unseen cap's area: the sphere's area the cameras do not see.
    unseen = (1 - seen.mean()) * 4 * np.pi * 0.1**2
    assert coverage.unseen_area_m2 == pytest.approx(unseen, rel=0.2)

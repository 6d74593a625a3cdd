"""What of a surface is observable at all, and the completeness judged against it."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from reconstruction.evaluation.metrics import TriangleSurface, sample_surface, surface_metrics
from reconstruction.evaluation.observable import observable_mask, working_distance_m

CENTRE = np.array([0.4, 0.0, 1.0])


def _sphere(radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    m = o3d.geometry.TriangleMesh.create_sphere(radius_m, resolution=40)
    return np.asarray(m.vertices) + CENTRE, np.asarray(m.triangles)


def test_a_convex_object_is_observable_all_over():
    v, t = _sphere(0.1)
    surface = TriangleSurface(v, t)
    samples = sample_surface(surface, 20_000)
    assert observable_mask(samples, surface, 0.5).all()


def test_a_surface_enclosed_by_another_is_not_observable():
    """A sphere inside a sphere: the inner one faces outwards, yet no camera outside sees it.
    Samples are area-uniform, so the observable share is the outer sphere's share of the area:
    0.1^2 / (0.1^2 + 0.05^2) = 0.8."""
    vo, to = _sphere(0.1)
    vi, ti = _sphere(0.05)
    surface = TriangleSurface(np.vstack([vo, vi]), np.vstack([to, ti + len(vo)]))
    samples = sample_surface(surface, 40_000)
    can = observable_mask(samples, surface, 0.5)
    inner = np.linalg.norm(samples.points - CENTRE, axis=1) < 0.075
    assert not can[inner].any() and can[~inner].all()
    assert can.mean() == pytest.approx(0.8, abs=0.01)


def test_completeness_against_the_observable_surface_leaves_out_what_none_could_see():
    d_tr = np.array([0.0005, 0.001, 0.003, 0.010, 0.010])  # truth samples -> model (m)
    observable = np.array([True, True, True, False, False])
    m = surface_metrics(np.full(3, 0.0005), d_tr, observable=observable)
    assert m["observable_fraction"] == pytest.approx(0.6)
    assert m["completeness_2mm"] == pytest.approx(0.4)
    assert m["completeness_observable_2mm"] == pytest.approx(2 / 3)
    assert "completeness_observable_2mm" not in surface_metrics(np.full(3, 0.0005), d_tr)


def test_the_working_distance_is_the_median_camera_distance():
    v, t = _sphere(0.1)
    eyes = [
        CENTRE + [0, 0, 0.5],
        CENTRE + [0.3, 0, 0],
        np.array([CENTRE + [-0.7, 0.06, 0], CENTRE + [-0.7, -0.06, 0]]),
    ]
    assert working_distance_m(TriangleSurface(v, t), eyes) == pytest.approx(0.5, abs=1e-3)

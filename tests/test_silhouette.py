"""Silhouette agreement of meshes and clouds against analytic silhouettes of a sphere and a
flat square."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, rotation_about, transform_points
from reconstruction.evaluation.silhouette import (
    cloud_silhouette_agreement,
    pixel_rays_C,
    silhouette_agreement,
)

WIDTH, HEIGHT = 320, 240
K = np.array([[400.0, 0.0, 161.3], [0.0, 398.0, 118.7], [0.0, 0.0, 1.0]])
# A camera neither at the origin nor axis-aligned, so that the pose is used the right way round.
X_WC = make_pose(rotation_about([0.3, -1.0, 0.5], 0.7), [0.2, -0.1, 0.4])
RADIUS_M = 0.1
STANDOFF_M = 0.6


def _sphere_mask(p_C: np.ndarray, radius_m: float) -> np.ndarray:
    """The exact silhouette of a sphere centred at p_C: rays within the cone that touches it."""
    d = pixel_rays_C(K, WIDTH, HEIGHT)
    along = d @ p_C
    return (along > 0) & (along**2 >= (d * d).sum(axis=-1) * (p_C @ p_C - radius_m**2))


def _sphere_mesh(p_C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=RADIUS_M, resolution=60)
    vertices_W = transform_points(X_WC, np.asarray(mesh.vertices) + p_C)
    return vertices_W, np.asarray(mesh.triangles)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return np.count_nonzero(a & b) / np.count_nonzero(a | b)


P_C = np.array([0.03, -0.02, STANDOFF_M])  # off the axis: the silhouette is an ellipse
MASK = _sphere_mask(P_C, RADIUS_M)


def test_the_true_sphere_mesh_agrees_with_its_analytic_silhouette():
    vertices_W, triangles = _sphere_mesh(P_C)
    result = silhouette_agreement(vertices_W, triangles, [(K, X_WC, WIDTH, HEIGHT, MASK)])
    # Inscribed facets of a 60-step UV sphere fall short of the sphere by R (1 - cos(pi/120))
    # = 34 um, 0.02 px at 0.6 m: only pixel centres within that of the outline can differ.
    assert result.median_iou > 0.995
    assert result.worst_coverage > 0.995


def test_a_shifted_sphere_scores_the_analytic_overlap():
    shift_C = np.array([0.04, 0.0, 0.0])  # 27 px sideways, about 0.4 of the radius in pixels
    vertices_W, triangles = _sphere_mesh(P_C + shift_C)
    views = [(K, X_WC, WIDTH, HEIGHT, MASK)]
    result = silhouette_agreement(vertices_W, triangles, views)
    shifted = _sphere_mask(P_C + shift_C, RADIUS_M)
    expected_iou = _iou(shifted, MASK)
    expected_coverage = np.count_nonzero(shifted & MASK) / np.count_nonzero(MASK)
    assert 0.4 < expected_iou < 0.8  # the shift is large enough to be a real test
    assert result.iou[0] == pytest.approx(expected_iou, abs=0.005)
    assert result.coverage[0] == pytest.approx(expected_coverage, abs=0.005)


def _square(side_m: float, offset_x_m: float, points_per_side: int = 0):
    """A flat square facing the camera at the standoff, as 2 triangles or as a grid of points."""
    h = side_m / 2
    if points_per_side:
        s = np.linspace(-h, h, points_per_side)
        x, y = np.meshgrid(s + offset_x_m, s)
        p_C = np.stack([x.ravel(), y.ravel(), np.full(x.size, STANDOFF_M)], axis=1)
        return transform_points(X_WC, p_C)
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]]) + [offset_x_m, 0.0]
    p_C = np.column_stack([corners, np.full(4, STANDOFF_M)])
    return transform_points(X_WC, p_C), np.array([[0, 1, 2], [0, 2, 3]])


SIDE_M = 0.15  # 100 px at 400 px focal length and 0.6 m
SHIFT_M = 0.03  # 20 px


def _square_mask() -> np.ndarray:
    vertices_W, triangles = _square(SIDE_M, 0.0)
    from reconstruction.evaluation.silhouette import MaskedView, mesh_silhouette

    empty = np.zeros((HEIGHT, WIDTH), bool)
    return mesh_silhouette(vertices_W, triangles, MaskedView(K, X_WC, WIDTH, HEIGHT, empty))


def test_a_shifted_square_scores_the_closed_form_overlap():
    mask = _square_mask()
    # The square's side in pixels, and the rendered one: the rendering is exact to a pixel row.
    side_px = SIDE_M * K[0, 0] / STANDOFF_M
    assert np.count_nonzero(mask.any(axis=0)) == pytest.approx(side_px, abs=1)
    vertices_W, triangles = _square(SIDE_M, SHIFT_M)
    result = silhouette_agreement(vertices_W, triangles, [(K, X_WC, WIDTH, HEIGHT, mask)])
    # Two equal squares of side L shifted by s along a side: IoU (L - s) / (L + s).
    assert result.iou[0] == pytest.approx((SIDE_M - SHIFT_M) / (SIDE_M + SHIFT_M), abs=0.01)
    assert result.coverage[0] == pytest.approx((SIDE_M - SHIFT_M) / SIDE_M, abs=0.01)


def _fibonacci_sphere(n: int) -> np.ndarray:
    """n points spread evenly over the unit sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def test_a_sampled_sphere_cloud_agrees_with_the_analytic_silhouette():
    spacing_m = 2e-3  # 1.3 px at the standoff
    n = int(4 * math.pi * RADIUS_M**2 / spacing_m**2)
    p_C = _fibonacci_sphere(n) * RADIUS_M + P_C
    # A hole stereo might leave (a dark patch 8 mm = 5 px across, facing the camera): closed.
    facing = p_C[:, 2] < P_C[2] - RADIUS_M + 0.004**2 / (2 * RADIUS_M)
    assert 5 < np.count_nonzero(facing) < 20
    points_W = transform_points(X_WC, p_C[~facing])
    views = [(K, X_WC, WIDTH, HEIGHT, MASK)]
    result = cloud_silhouette_agreement(points_W, views)
    # The splat pushes the outline out by about half a spacing, 0.7 px on a 70 px radius.
    assert result.median_coverage > 0.995
    assert result.median_iou > 0.97


def test_a_shifted_square_cloud_scores_the_closed_form_overlap():
    mask = _square_mask()
    points_W = _square(SIDE_M, SHIFT_M, points_per_side=76)  # 2 mm pitch, 1.3 px
    result = cloud_silhouette_agreement(points_W, [(K, X_WC, WIDTH, HEIGHT, mask)])
    assert result.iou[0] == pytest.approx((SIDE_M - SHIFT_M) / (SIDE_M + SHIFT_M), abs=0.02)
    assert result.coverage[0] == pytest.approx((SIDE_M - SHIFT_M) / SIDE_M, abs=0.02)


def test_a_mask_of_the_wrong_size_is_a_user_error():
    vertices_W, triangles = _sphere_mesh(P_C)
    with pytest.raises(ScannerError, match="mask of view 0"):
        silhouette_agreement(vertices_W, triangles, [(K, X_WC, WIDTH, HEIGHT, MASK.T)])

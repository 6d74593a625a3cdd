"""Voxel averaging in NumPy against Open3D's `voxel_down_sample` on the same grid, and the fused
cloud built on it."""

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.common.voxels import voxel_means
from reconstruction.registration.filtering import FilterCounts, FilteredCloud, o3d_cloud
from reconstruction.surfaces.fused import fuse_clouds


def _noisy_sphere(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = 0.05 * d + rng.normal(scale=3e-4, size=(n, 3)) + [0.4, 0.0, 1.0]
    colors = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    return points, d, colors


def _rows_sorted(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


def test_the_cells_and_their_means_are_open3ds():
    points, normals, colors = _noisy_sphere(60_000)
    ours = voxel_means(points, 0.001, normals, colors / 255.0)
    theirs = o3d_cloud(points, normals, colors).voxel_down_sample(0.001)
    ours_rows = np.hstack(ours)
    theirs_rows = np.hstack(
        [np.asarray(theirs.points), np.asarray(theirs.normals), np.asarray(theirs.colors)]
    )
    assert ours_rows.shape == theirs_rows.shape
    # Summed in the same (point) order per cell: the same numbers, only the cells' order differs.
    np.testing.assert_allclose(_rows_sorted(ours_rows), _rows_sorted(theirs_rows), atol=1e-15)


def test_each_mean_is_that_of_the_points_in_its_cell():
    points = np.array([[0.0, 0.0, 0.0], [0.0004, 0.0, 0.0], [0.003, 0.0, 0.0], [0.0031, 0, 0]])
    weights = np.array([[1.0], [3.0], [10.0], [20.0]])
    means, w = voxel_means(points, 0.001, weights)
    # The grid starts half a cell below the minimum: cells [-0.5, 0.5) mm and [2.5, 3.5) mm.
    np.testing.assert_allclose(means, [[0.0002, 0, 0], [0.00305, 0, 0]])
    np.testing.assert_allclose(w, [[2.0], [15.0]])


def test_bad_input_is_refused():
    with pytest.raises(ScannerError, match="voxel_m"):
        voxel_means(np.zeros((3, 3)), 0.0)
    with pytest.raises(ScannerError, match=r"\(N, 3\)"):
        voxel_means(np.zeros((3, 2)), 0.001)
    with pytest.raises(ScannerError, match="attribute"):
        voxel_means(np.zeros((3, 3)), 0.001, np.zeros((2, 3)))
    empty, attribute = voxel_means(np.zeros((0, 3)), 0.001, np.zeros((0, 3)))
    assert empty.shape == (0, 3) and attribute.shape == (0, 3)


def test_the_fused_cloud_is_what_open3d_fused_and_the_same_every_time():
    points, normals, colors = _noisy_sphere(40_000, seed=1)
    counts = FilterCounts(20_000, 20_000, 20_000, 20_000, 20_000)
    halves = [
        FilteredCloud(k, points[k::2] - [0.4, 0.0, 1.0], colors[k::2], normals[k::2], counts)
        for k in range(2)
    ]
    X = np.eye(4)
    X[:3, 3] = [0.4, 0.0, 1.0]
    fused = fuse_clouds(halves, [X, X], 0.002)
    again = fuse_clouds(halves, [X, X], 0.002)
    np.testing.assert_array_equal(fused.points_W, again.points_W)
    # The fused cloud stacks the views in order: Open3D given the same order sums alike.
    stacked = [np.vstack([a[0::2], a[1::2]]) for a in (points, normals, colors)]
    theirs = o3d_cloud(*stacked).voxel_down_sample(0.002)
    np.testing.assert_allclose(
        _rows_sorted(fused.points_W), _rows_sorted(np.asarray(theirs.points)), atol=1e-15
    )
    expected_colors = np.clip(np.round(np.asarray(theirs.colors) * 255), 0, 255)
    ours = np.hstack([fused.points_W, fused.colors])
    want = np.hstack([np.asarray(theirs.points), expected_colors])
    np.testing.assert_array_equal(_rows_sorted(ours)[:, 3:], _rows_sorted(want)[:, 3:])
    assert np.allclose(np.linalg.norm(fused.normals_W, axis=1), 1.0)

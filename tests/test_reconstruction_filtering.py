"""Per-view filtering: region of interest, voxel centroids, outliers, the caller's hook, normals."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose
from reconstruction.registration.filtering import FilterConfig, RegionOfInterest, filter_view


def _plane_C(n: int = 80, spacing_m: float = 0.001, depth_m: float = 0.5) -> np.ndarray:
    """A fronto-parallel square of points 0.5 m in front of the camera."""
    u = (np.arange(n) - n / 2) * spacing_m
    x, y = np.meshgrid(u, u)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, depth_m)], axis=1)


def _grey(n: int) -> np.ndarray:
    return np.full((n, 3), 128, np.uint8)


X_WC_SHIFTED = make_pose(np.eye(3), [1.0, 2.0, 3.0])


def test_roi_crops_in_the_world_frame():
    p = _plane_C()
    # Centre of the square in W is (1, 2, 3.5); a 20.5 mm sphere there keeps a disc
    # (not 20 mm: grid points on the boundary would make the count a rounding question).
    roi = RegionOfInterest("sphere", (1.0, 2.0, 3.5), radius_m=0.0205)
    cfg = FilterConfig(roi=roi, voxel_size_m=1e-5, outlier_neighbors=0)
    out = filter_view(0, p, _grey(len(p)), X_WC_SHIFTED, cfg)
    assert out.counts.after_roi == np.sum(np.linalg.norm(p[:, :2], axis=1) <= 0.0205)
    assert np.all(np.linalg.norm(out.points_C[:, :2], axis=1) <= 0.0205)
    box = RegionOfInterest("box", (1.0, 2.0, 3.5), half_extent_m=(0.01, 0.005, 0.1))
    out = filter_view(0, p, _grey(len(p)), X_WC_SHIFTED, FilterConfig(roi=box, outlier_neighbors=0))
    assert np.all(np.abs(out.points_C[:, 0]) <= 0.01) and np.all(
        np.abs(out.points_C[:, 1]) <= 0.005
    )


def test_no_centre_means_no_crop():
    p = _plane_C(20)
    out = filter_view(0, p, _grey(len(p)), np.eye(4), FilterConfig(outlier_neighbors=0))
    assert out.counts.after_roi == len(p)


def test_voxel_downsampling_keeps_centroids():
    # Open3D starts the grid half a voxel below the minimum: eight points spread over less than
    # half a voxel share one voxel and collapse to their centroid, colours averaged.
    rng = np.random.default_rng(0)
    p = 0.5 + rng.random((8, 3)) * 0.0009
    colors = np.array([[0, 0, 0], [255, 255, 255]] * 4, np.uint8)
    cfg = FilterConfig(voxel_size_m=0.002, outlier_neighbors=0, min_points=3)
    out = filter_view(0, p, colors, np.eye(4), cfg)
    assert len(out) == 1
    np.testing.assert_allclose(out.points_C[0], p.mean(axis=0), atol=1e-12)
    assert np.all(np.abs(out.colors[0].astype(int) - 128) <= 1)


def test_statistical_outliers_are_removed_and_normals_face_the_camera():
    p = _plane_C()
    stray = np.array([[0.0, 0.0, 0.45], [0.01, -0.02, 0.56]])  # 50-60 mm off the surface
    out = filter_view(
        0, np.vstack([p, stray]), _grey(len(p) + 2), np.eye(4), FilterConfig(voxel_size_m=1e-4)
    )
    assert out.counts.after_outliers <= len(p)
    assert not np.any(np.abs(out.points_C[:, 2] - 0.5) > 0.01)
    # The plane faces the camera at the origin: normals point to -z.
    assert np.all(out.normals_C[:, 2] < -0.99)


def test_nan_points_are_dropped():
    p = _plane_C(10)
    p[3] = np.nan
    out = filter_view(0, p, _grey(len(p)), np.eye(4), FilterConfig(outlier_neighbors=0))
    assert np.all(np.isfinite(out.points_C)) and len(out) == len(p) - 1


def test_remove_points_hook_is_honoured_in_the_world_frame():
    p = _plane_C()
    seen = {}

    def remove_right_half(points_W: np.ndarray, view_index: int) -> np.ndarray:
        seen["index"] = view_index
        seen["min_z"] = points_W[:, 2].min()
        return points_W[:, 0] < 1.0  # x_W < 1 m is x_C < 0

    out = filter_view(
        7,
        p,
        _grey(len(p)),
        X_WC_SHIFTED,
        FilterConfig(voxel_size_m=1e-4, outlier_neighbors=0),
        remove_right_half,
    )
    assert seen["index"] == 7 and seen["min_z"] == pytest.approx(3.5)  # it got W points
    assert np.all(out.points_C[:, 0] < 0) and out.counts.after_hook == np.sum(p[:, 0] < 0)


def test_a_hook_returning_the_wrong_thing_is_a_programming_error():
    p = _plane_C(10)
    with pytest.raises(TypeError, match="keep mask"):
        filter_view(
            0,
            p,
            _grey(len(p)),
            np.eye(4),
            FilterConfig(outlier_neighbors=0),
            lambda pts, i: np.ones(len(pts)),
        )


@pytest.mark.parametrize(
    "make",
    [
        lambda: RegionOfInterest("cube"),
        lambda: RegionOfInterest(radius_m=-1.0),
        lambda: RegionOfInterest(center_m=(0.0, float("nan"), 0.0)),
        lambda: FilterConfig(voxel_size_m=0.0),
    ],
)
def test_bad_settings_are_user_errors(make):
    with pytest.raises(ScannerError):
        make()

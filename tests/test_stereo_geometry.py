"""Stereo geometry without rendering: the model's projections, Q, R1 and the disparity window."""

import cv2
import numpy as np
import pytest

from reconstruction.stereo.camera_model import default_stereo_camera
from reconstruction.stereo.cloud import points_from_disparity, reproject
from reconstruction.stereo.matching import compute_disparity
from reconstruction.stereo.params import disparity_window
from reconstruction.stereo.rectification import compute_rectification

# undistortPoints must invert k1 = -0.42 to far below a micrometre at 0.5 m (1e-6 m = 0.003 px).
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)


def _rectified(cam, rotation, projection, pixels):
    return cv2.undistortPointsIter(
        pixels.reshape(-1, 1, 2), cam.K, cam.distortion, rotation, projection, UNDISTORT_CRITERIA
    ).reshape(-1, 2)


@pytest.mark.parametrize("verged", [False, True])
def test_project_and_reproject_round_trip(verged):
    """p_C -> distorted pixels in both cameras -> rectified -> (u, v, d) -> Q, R1^T -> p_C."""
    model = default_stereo_camera()
    if verged:  # a real rig is never perfectly parallel: 1 deg toe-in, 2 mm height offset
        from reconstruction.stereo.camera_model import StereoCamera

        angle = np.radians(1.0)
        R = np.array(
            [[np.cos(angle), 0, -np.sin(angle)], [0, 1, 0], [np.sin(angle), 0, np.cos(angle)]]
        )
        model = StereoCamera(model.left, model.right, R, np.array([-0.12, 0.002, 0.0]))
    rect = compute_rectification(model)
    rng = np.random.default_rng(7)
    z = rng.uniform(0.35, 0.7, 500)
    xy = rng.uniform(-0.25, 0.25, (500, 2)) * z[:, None]
    p_C = np.column_stack([xy, z])
    p_R = p_C @ model.R.T + model.T
    px_left, _ = cv2.projectPoints(
        p_C, np.zeros(3), np.zeros(3), model.left.K, model.left.distortion
    )
    px_right, _ = cv2.projectPoints(
        p_R, np.zeros(3), np.zeros(3), model.right.K, model.right.distortion
    )
    uv_left = _rectified(model.left, rect.R1, rect.P1, px_left)
    uv_right = _rectified(model.right, rect.R2, rect.P2, px_right)
    assert np.abs(uv_left[:, 1] - uv_right[:, 1]).max() < 1e-6  # px: rows are epipolar lines
    uvd = np.column_stack([uv_left, uv_left[:, 0] - uv_right[:, 0]])
    p_back = points_from_disparity(rect, uvd)
    assert np.abs(p_back - p_C).max() < 1e-6  # m


def test_dense_reprojection_lands_on_the_source_pixels():
    """A constant disparity image becomes points that project back onto the maps' pixels."""
    model = default_stereo_camera()
    rect = compute_rectification(model)
    fb = rect.focal_px * rect.baseline_m
    disparity = np.full((960, 1280), np.nan, np.float32)
    disparity[400:500, 700:800] = fb / 0.5  # a fronto-parallel patch at 0.5 m
    image = np.full((960, 1280, 3), (10, 20, 30), np.uint8)
    cloud = reproject(rect, disparity, image, 0.4, 0.6)
    assert len(cloud) == 100 * 100
    assert np.allclose(cloud.points_C[:, 2], 0.5, atol=1e-9)
    projected, _ = cv2.projectPoints(
        cloud.points_C, np.zeros(3), np.zeros(3), model.left.K, model.left.distortion
    )
    assert np.abs(projected.reshape(-1, 2) - cloud.pixels_left).max() < 0.01  # px
    assert np.all(cloud.colors == (10, 20, 30))
    assert len(reproject(rect, disparity, image, 0.55, 0.6)) == 0  # outside the window: dropped


def test_disparity_window_follows_depth():
    fb = 1243.0 * 0.12
    min_d, num_d = disparity_window(0.4, 0.6, 1243.0, 0.12)
    assert num_d % 16 == 0 and min_d <= fb / 0.6 and min_d + num_d - 1 >= fb / 0.4
    near = disparity_window(0.2, 0.3, 1243.0, 0.12)
    assert near[0] > min_d + num_d  # nearer objects: larger disparities, never a constant
    assert disparity_window(0.4, 0.6, 1243.0, 0.24)[1] > num_d  # longer baseline: wider search


def test_compute_disparity_recovers_a_known_shift():
    """A random texture shifted by 37.25 px: matched pixels report it within a quarter pixel."""
    rng = np.random.default_rng(1)
    texture = cv2.resize(rng.uniform(0, 255, (120, 170)), (680, 480), cv2.INTER_CUBIC)
    shift = 37.25
    M = np.float32([[1, 0, -shift], [0, 1, 0]])
    right = cv2.warpAffine(texture, M, (680, 480), flags=cv2.INTER_CUBIC)
    left8, right8 = (
        np.clip(texture, 0, 255).astype(np.uint8),
        np.clip(right, 0, 255).astype(np.uint8),
    )
    disparity = compute_disparity(left8, right8, 16, 48)
    assert disparity.dtype == np.float32 and disparity.shape == left8.shape
    inner = disparity[20:-20, 100:-20]
    assert np.isfinite(inner).mean() > 0.95
    # SGBM's parabola fit is pulled towards whole pixels ("pixel locking"): measured 0.19 px
    # at a quarter-pixel shift, i.e. up to 0.3 mm at 0.5 m; the sign and scale are what count.
    assert np.nanmedian(np.abs(inner - shift)) < 0.25
    assert np.all(np.isnan(disparity[:, :16]))  # no match can exist left of min_disparity
    grey_and_rgb = compute_disparity(np.dstack([left8] * 3), np.dstack([right8] * 3), 16, 48)
    assert np.array_equal(np.isnan(grey_and_rgb), np.isnan(disparity))


def test_half_occlusion_next_to_a_step():
    """Background (d = 10 px) left of a foreground edge at column 50 (d = 20 px): the right
    camera, 20 - 10 px further left for the foreground, cannot see columns 40..49."""
    from reconstruction.stereo.metrics import hidden_from_right

    row = np.full((1, 100), 10.0, np.float32)
    row[0, 50:] = 20.0
    row[0, 95:] = np.nan  # nothing there
    hidden = hidden_from_right(row)[0]
    assert np.array_equal(np.nonzero(hidden)[0], np.arange(40, 50))

"""The simulated stereo camera: textured renders, true geometry, true distortion, seeded noise."""

import cv2
import numpy as np
import pytest

from reconstruction.stereo.rectification import compute_rectification, rectify_pair
from robots.simulation.stereo_camera import distortion_maps


@pytest.fixture(scope="module")
def pair_and_truth(vase_sim, view_q):
    vase_sim.robot.teleport(view_q)
    return vase_sim.camera.capture(), vase_sim.camera.ground_truth()


def test_object_is_textured_in_both_images(pair_and_truth):
    pair, gt = pair_and_truth
    assert gt.object_mask.sum() > 50_000  # ~0.2 m object at 0.5 m covers ~1/5 of the image
    gray = cv2.cvtColor(pair.left, cv2.COLOR_RGB2GRAY).astype(float)
    local_std = np.sqrt(np.maximum(cv2.blur(gray**2, (7, 7)) - cv2.blur(gray, (7, 7)) ** 2, 0))
    inner = cv2.erode(gt.object_mask.astype(np.uint8), np.ones((15, 15))).astype(bool)
    # Untextured (flat-shaded) surfaces give a local std of ~noise (2 levels); texture >> that.
    assert np.median(local_std[inner]) > 15.0
    assert pair.right.std() > 10.0


def test_distortion_maps_invert_the_camera_model(vase_sim):
    cam = vase_sim.truth.stereo.left
    maps = distortion_maps(cam)
    rng = np.random.default_rng(0)
    u = rng.uniform(0, cam.width - 1, 500)
    v = rng.uniform(0, cam.height - 1, 500)
    mx = cv2.remap(
        maps.map_x, u.astype(np.float32)[None], v.astype(np.float32)[None], cv2.INTER_LINEAR
    )[0]
    my = cv2.remap(
        maps.map_y, u.astype(np.float32)[None], v.astype(np.float32)[None], cv2.INTER_LINEAR
    )[0]
    K_r = maps.K_render
    rays = np.stack(
        [(mx - K_r[0, 2]) / K_r[0, 0], (my - K_r[1, 2]) / K_r[1, 1], np.ones_like(mx)], 1
    )
    projected, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, cam.distortion)
    err = np.linalg.norm(projected.reshape(-1, 2) - np.stack([u, v], 1), axis=1)
    assert err.max() < 0.05  # px: the lookup reproduces OpenCV's distortion model
    undist = cv2.undistortPointsIter(
        projected,
        cam.K,
        cam.distortion,
        None,
        None,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
    )
    assert np.abs(undist.reshape(-1, 2) - rays[:, :2]).max() * cam.K[0, 0] < 0.05


def _ncc_shift(left, right, u, v, predicted_shift, half=12, search=6):
    """Sub-pixel horizontal shift of the patch at (u, v) of `left` found in `right`."""
    patch = left[v - half : v + half + 1, u - half : u + half + 1]
    u0 = int(round(u - predicted_shift)) - search
    strip = right[v - half : v + half + 1, u0 - half : u0 + 2 * search + half + 1]
    scores = cv2.matchTemplate(strip, patch, cv2.TM_CCOEFF_NORMED)[0]
    k = int(np.argmax(scores))
    if not 0 < k < len(scores) - 1 or scores[k] < 0.8:
        return None
    a, b, c = scores[k - 1 : k + 2]
    offset = 0.5 * (a - c) / (a - 2 * b + c)
    return u - (u0 + k + offset)


def test_rectified_shift_equals_f_b_over_z(vase_sim, pair_and_truth):
    pair, gt = pair_and_truth
    stereo = vase_sim.truth.stereo
    rect = compute_rectification(stereo)
    left, right = (
        cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in rectify_pair(rect, pair.left, pair.right)
    )
    # Sample object pixels away from silhouettes, lift them to 3D with the TRUE depth.
    inner = cv2.erode(gt.object_mask.astype(np.uint8), np.ones((41, 41))).astype(bool)
    vs, us = np.nonzero(inner)
    pick = np.random.default_rng(1).choice(len(us), 60, replace=False)
    px = np.stack([us[pick], vs[pick]], 1).astype(np.float64)
    z = gt.depth_m[vs[pick], us[pick]].astype(float)
    xy = cv2.undistortPointsIter(
        px.reshape(-1, 1, 2),
        stereo.left.K,
        stereo.left.distortion,
        None,
        None,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
    )
    p_C = np.column_stack([xy.reshape(-1, 2) * z[:, None], z])
    p_rect = p_C @ rect.R1.T
    f, b = rect.focal_px, rect.baseline_m
    u_rect = f * p_rect[:, 0] / p_rect[:, 2] + rect.P1[0, 2]
    v_rect = f * p_rect[:, 1] / p_rect[:, 2] + rect.P1[1, 2]
    errors = []
    for ur, vr, zr in zip(u_rect, v_rect, p_rect[:, 2]):
        expected = f * b / zr
        measured = _ncc_shift(left, right, int(round(ur)), int(round(vr)), expected)
        if measured is not None:
            errors.append(measured - expected)
    errors = np.abs(np.array(errors))
    assert len(errors) >= 30
    assert np.median(errors) < 0.5  # px
    assert np.percentile(errors, 80) < 0.5


def test_same_seed_same_images_different_seed_different_noise(view_q):
    from robots.models.workcell import WorkcellConfig
    from robots.simulation.cell import create_simulation
    from robots.simulation.truth import ErrorModel

    def first_pair(seed):
        sim = create_simulation(WorkcellConfig(), "vase", ErrorModel(seed=seed))
        sim.robot.teleport(view_q)
        return sim.camera.capture()

    a, b, c = first_pair(5), first_pair(5), first_pair(6)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    diff = np.abs(a.left.astype(int) - c.left.astype(int))
    assert diff.mean() > 0.5  # noise and hand-eye error differ between seeds


def test_sensor_noise_has_the_error_models_spread_and_no_bias(view_q):
    from robots.models.workcell import WorkcellConfig
    from robots.simulation.cell import create_simulation
    from robots.simulation.truth import ErrorModel

    def first_pair(noise_std):
        sim = create_simulation(
            WorkcellConfig(), "vase", ErrorModel(seed=3, image_noise_std=noise_std)
        )
        sim.robot.teleport(view_q)
        return sim.camera.capture()

    clean, noisy = first_pair(0.0), first_pair(4.0)
    # Only grey levels away from 0 and 255, where clipping does not bend the distribution.
    inside = (clean.left > 20) & (clean.left < 235)
    diff = noisy.left.astype(float)[inside] - clean.left.astype(float)[inside]
    # Rounding to whole levels adds 1/12 level^2 and no bias.
    assert abs(diff.mean()) < 0.05
    assert abs(diff.std() - np.sqrt(4.0**2 + 1 / 12)) < 0.1

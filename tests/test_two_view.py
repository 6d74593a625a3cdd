"""Stereo from two poses of one camera (reconstruction/two_view): pairing, quarter turns,
epipolar check and refinement, pair clouds. Synthetic cases have exact answers; the real case is
DTU MVS scan 24 (camera on an industrial arm), downscaled 4x to 400x300 to stay fast."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from conftest import shared_data

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import (
    invert,
    make_pose,
    pose_difference,
    rotation_about,
    rotation_between,
    transform_points,
)
from reconstruction.stereo.camera_model import PinholeCamera, project_points
from reconstruction.stereo.cloud import sample_image
from reconstruction.stereo.params import StereoParams
from reconstruction.two_view.cloud import TwoViewConfig, pair_cloud
from reconstruction.two_view.epipolar import (
    EpipolarConfig,
    checked_pose,
    error_of,
    match_features,
)
from reconstruction.two_view.pairing import PairingConfig, pair_views
from reconstruction.two_view.rectification import (
    pair_rig,
    rectifying_rotations,
    rotate_camera,
    rotate_image,
)
from reconstruction.two_view.scaling import downscaled_camera, downscaled_image, downscaled_mask

DTU = "real/dtu_mvs_scan24"
DTU_VIEWS = (0, 1, 9, 10)  # 0-1 and 9-10 side by side, 1-9 and 0-10 one above the other
DOWNSCALE = 4


def _looking_at(p_W_eye: np.ndarray, p_W_target: np.ndarray) -> np.ndarray:
    """X_WC of a camera at p_W_eye whose optical axis (+z) points at p_W_target, +y down-ish."""
    z = (p_W_target - p_W_eye) / np.linalg.norm(p_W_target - p_W_eye)
    x = np.cross([0.0, 0.0, 1.0], z)
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    return make_pose(np.column_stack([x, np.cross(z, x), z]), p_W_eye)


def _sphere_poses(azimuths_deg, elevations_deg, radius_m=0.5):
    """Cameras on a sphere around the origin, all looking at it; (index -> (row, column))."""
    poses, grid = [], {}
    for r, elevation in enumerate(elevations_deg):
        for c, azimuth in enumerate(azimuths_deg):
            a, e = math.radians(azimuth), math.radians(elevation)
            eye = radius_m * np.array(
                [math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)]
            )
            grid[len(poses)] = (r, c)
            poses.append(_looking_at(eye, np.zeros(3)))
    return poses, grid


# --- pairing ------------------------------------------------------------------------------------


def test_ring_pairs_each_view_with_its_neighbours():
    poses, _ = _sphere_poses(np.arange(0, 360, 10), [0.0])
    pairs = pair_views(poses, np.zeros(3), PairingConfig(pairs_per_view=2))
    assert len(pairs) == 2 * 36
    chord_m = 2 * 0.5 * math.sin(math.radians(5))
    for pair in pairs:
        assert (pair.other - pair.reference) % 36 in (1, 35)
        assert pair.baseline_m == pytest.approx(chord_m, rel=1e-9)
        assert pair.angle_rad == pytest.approx(math.radians(10), rel=1e-6)
    assert {p.reference for p in pairs} == set(range(36))


def test_vertical_neighbours_pair_when_horizontal_ones_are_too_far():
    # Rows 8 deg apart, columns 30 deg apart (beyond max_angle_rad 25 deg): only vertical pairs.
    poses, grid = _sphere_poses([0, 30, 60], [-8, 0, 8])
    pairs = pair_views(poses, np.zeros(3), PairingConfig())
    assert len(pairs) == len(poses)
    for pair in pairs:
        (r0, c0), (r1, c1) = grid[pair.reference], grid[pair.other]
        assert c0 == c1 and abs(r0 - r1) == 1
    # And such a pair's rig turns the images a quarter turn (the baseline is along y).
    pair = pairs[4]  # the centre view
    X_CO = invert(poses[pair.reference]) @ poses[pair.other]
    camera = PinholeCamera(
        np.array([[500.0, 0, 160], [0, 500, 120], [0, 0, 1]]), np.zeros(5), 320, 240
    )
    assert pair_rig(camera, camera, X_CO).quarter_turns in (1, 3)


def test_no_partner_names_the_limit():
    poses, _ = _sphere_poses([0, 2, 4], [0.0])  # 2 deg apart: below min_angle_rad (4 deg)
    with pytest.raises(ScannerError, match=r"pairing\.min_angle_rad"):
        pair_views(poses, np.zeros(3), PairingConfig())
    with pytest.raises(ScannerError, match=r"pairing\.max_baseline_ratio"):
        pair_views(
            poses,
            np.zeros(3),
            PairingConfig(min_angle_rad=0.01, min_baseline_ratio=0.01, max_baseline_ratio=0.02),
        )


# --- quarter turns ------------------------------------------------------------------------------


@pytest.mark.parametrize("quarter_turns", [1, 2, 3])
def test_turned_camera_sees_the_turned_image(quarter_turns):
    """A distorted camera's projection, turned with the image, equals the turned camera's
    projection of the same points in the turned frame V (distortion included, exactly)."""
    K = np.array([[800.0, 0, 330.5], [0, 790.0, 236.25], [0, 0, 1]])
    camera = PinholeCamera(K, np.array([-0.2, 0.1, 0.002, -0.001, 0.01]), 640, 480)
    turned, R_CV = rotate_camera(camera, quarter_turns)
    rng = np.random.default_rng(3)
    p_C = np.column_stack([rng.uniform(-0.15, 0.15, (200, 2)), np.full(200, 0.5)])
    uv = project_points(camera, p_C)
    # np.rot90 moves pixel (u, v) of a W-wide image to (v, W - 1 - u), once per turn.
    marks = np.array([[10.0, 20.0], [600.0, 400.0], [37.0, 470.0]])
    image = np.zeros((480, 640), np.int32)
    image[marks[:, 1].astype(int), marks[:, 0].astype(int)] = [1, 2, 3]
    moved = rotate_image(image, quarter_turns)
    assert moved.shape[::-1] == (turned.width, turned.height)

    def turn(px: np.ndarray) -> np.ndarray:
        width = camera.width
        for _ in range(quarter_turns):
            px = np.column_stack([px[:, 1], width - 1 - px[:, 0]])
            width = camera.height if width == camera.width else camera.width
        return px

    moved_marks = turn(marks).astype(int)
    assert list(moved[moved_marks[:, 1], moved_marks[:, 0]]) == [1, 2, 3]
    # The same move applied to sub-pixel projections: the turned camera's, in V.
    np.testing.assert_allclose(turn(uv), project_points(turned, p_C @ R_CV), atol=1e-9)


def test_skewed_camera_is_refused_for_a_turn():
    K = np.array([[800.0, 0.5, 320], [0, 800, 240], [0, 0, 1]])
    camera = PinholeCamera(K, np.zeros(5), 640, 480)
    rotate_camera(camera, 0)  # no turn, no problem
    with pytest.raises(ScannerError, match=r"skew"):
        rotate_camera(camera, 1)


def test_bad_inputs_name_what_to_fix():
    camera = PinholeCamera(
        np.array([[480.0, 0, 159.5], [0, 480, 119.5], [0, 0, 1]]), np.zeros(5), 320, 240
    )
    image = np.zeros((240, 320), np.uint8)
    X_WCj = make_pose(np.eye(3), [0.06, 0, 0])
    args = (camera, camera, np.eye(4), X_WCj, np.array([0, 0, 0.5]), 0.1, StereoParams())
    with pytest.raises(
        ScannerError, match=r"other image is 160x120 px, its camera expects 320x240"
    ):
        pair_cloud(image, image[::2, ::2], *args)
    with pytest.raises(ScannerError, match=r"reference mask"):
        pair_cloud(image, image, *args, mask_i=np.ones((10, 10), bool))
    with pytest.raises(ScannerError, match=r"two_view\.downscale"):
        TwoViewConfig(downscale=0.5)
    with pytest.raises(ScannerError, match=r"pairing\.min_angle_rad"):
        PairingConfig(min_angle_rad=0.5, max_angle_rad=0.4)


# --- a synthetic textured plane: exact depths -----------------------------------------------------


# Plane of the synthetic pairs: centred 0.5 m ahead of W's origin, tilted by 25 deg (a
# fronto-parallel plane has one disparity everywhere, and SGBM's sub-pixel step locks onto it:
# a 0.1 px bias that a slanted plane averages out).
X_WP = make_pose(rotation_about([1.0, 1.0, 0.0], math.radians(25.0)), [0.0, 0.0, 0.5])
PLANE_SIDE_M = 0.6


def _texture(size_px: int, seed: int) -> np.ndarray:
    """Smooth random texture with blobs of about 4 texels (1.2 mm at 0.6 m / 512, a little
    more than an image pixel at 0.5 m and f 480 px: no aliasing in the rendering)."""
    noise = np.random.default_rng(seed).uniform(0, 255, (size_px // 4, size_px // 4))
    fine = cv2.resize(noise.astype(np.float32), (size_px, size_px), interpolation=cv2.INTER_CUBIC)
    return np.clip(fine, 0, 255).astype(np.uint8)


def _render_plane(camera: PinholeCamera, X_WC: np.ndarray, texture: np.ndarray) -> np.ndarray:
    """The image of the textured plane P (X_WP) seen by a pinhole camera at X_WC."""
    n, side = texture.shape[0], PLANE_SIDE_M
    # Texture pixel s (centres at integers) -> plane coordinate (s + 1/2) side / n - side / 2.
    offset = side / (2 * n) - side / 2
    S = np.array([[side / n, 0, offset], [0, side / n, offset], [0, 0, 1]])
    X_CP = invert(X_WC) @ X_WP
    H = camera.K @ np.column_stack([X_CP[:3, 0], X_CP[:3, 1], X_CP[:3, 3]]) @ S
    return cv2.warpPerspective(texture, H, (camera.width, camera.height), flags=cv2.INTER_LINEAR)


@pytest.mark.parametrize(
    ("p_W_other", "quarter_turns"),
    [((0.06, 0, 0), 0), ((0, 0.06, 0), 1), ((-0.06, 0, 0), 2), ((0, -0.06, 0.005), 3)],
)
def test_plane_depths_for_every_baseline_direction(p_W_other, quarter_turns):
    """Reference camera at W's origin, the other 60 mm to its right, below, left or above it,
    aimed at the plane's centre: the points in C lie on the plane, whichever turn the pair
    needed, and carry the reference image's texture at their pixels."""
    camera = PinholeCamera(
        np.array([[480.0, 0, 159.5], [0, 480, 119.5], [0, 0, 1]]), np.zeros(5), 320, 240
    )
    texture = _texture(512, 5)
    centre = X_WP[:3, 3]
    X_WCi = np.eye(4)
    eye = np.asarray(p_W_other, float)
    X_WCj = make_pose(rotation_between([0, 0, 1], centre - eye), eye)
    image_i = _render_plane(camera, X_WCi, texture)
    image_j = _render_plane(camera, X_WCj, texture)
    cloud = pair_cloud(
        image_i,
        image_j,
        camera,
        camera,
        X_WCi,
        X_WCj,
        centre,
        0.1,
        StereoParams(),
        config=TwoViewConfig(refine_pose=False),
    )
    assert cloud.quarter_turns == quarter_turns
    assert len(cloud) > 0.6 * camera.width * camera.height
    signed_m = (cloud.points_C - centre) @ X_WP[:3, 2]
    # A disparity pixel is 8.7 mm of depth here (0.5^2 / (480 * 0.06)); measured: median
    # |error| 0.5-0.6 mm (0.06 px), median signed error within 0.04 mm, p95 1.5 mm.
    assert abs(np.median(signed_m)) < 0.15e-3
    assert np.median(np.abs(signed_m)) < 0.8e-3
    assert np.percentile(np.abs(signed_m), 95) < 2.5e-3
    # Each point lies on the ray of the reference pixel whose colour it carries (whatever its
    # depth): the turn is undone exactly.
    pixels = project_points(camera, cloud.points_C)
    assert ((pixels >= 0) & (pixels <= [319, 239])).all()
    sampled = sample_image(image_i, pixels.astype(np.float32), cv2.INTER_LINEAR)
    colour_error = np.abs(sampled.astype(int) - cloud.colors[:, 0].astype(int))
    assert np.percentile(colour_error, 99) <= 1
    # The depth image: its pixels lifted through X_CD land on the plane too.
    depth = cloud.depth
    v, u = np.nonzero(depth.depth_m > 0)
    z = depth.depth_m[v, u]
    K = depth.K
    p_D = np.column_stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
    signed_depth_m = (transform_points(depth.X_CD, p_D) - centre) @ X_WP[:3, 2]
    assert len(z) > 0.6 * camera.width * camera.height
    assert np.median(np.abs(signed_depth_m)) < 0.8e-3


@pytest.mark.parametrize("roll_deg", [-10.0, 10.0])
@pytest.mark.parametrize(
    "p_C_other", [(0.06, -0.055, 0.0), (0.055, 0.06, 0.0), (-0.06, 0.055, 0.0)]
)
def test_near_diagonal_baseline_rectifies_along_rows(p_C_other, roll_deg):
    """A baseline 42 deg off the image's rows with 10 deg of roll between the views (DTU's
    views 10 and 13): after the quarter turn the baseline lies along x, and so it must after
    rectification (stereoRectify alone turned half of these cases vertical: baseline 0 along
    x, and the pair failed). Any point then images on one rectified row in both views, at a
    disparity f b / z."""
    camera = PinholeCamera(
        np.array([[480.0, 0, 159.5], [0, 480, 119.5], [0, 0, 1]]), np.zeros(5), 320, 240
    )
    eye = np.asarray(p_C_other)
    centre = np.array([0.0, 0.0, 0.5])
    roll = rotation_about(np.array([0.0, 0.0, 1.0]), math.radians(roll_deg))
    rig = pair_rig(camera, camera, make_pose(rotation_between([0, 0, 1], centre - eye) @ roll, eye))
    R1, R2, baseline_m = rectifying_rotations(rig)
    assert baseline_m == pytest.approx(np.linalg.norm(eye), rel=1e-9)
    p_V = np.random.default_rng(0).uniform([-0.1, -0.1, 0.4], [0.1, 0.1, 0.6], (50, 3))
    p_1 = p_V @ R1.T
    p_2 = (p_V @ rig.stereo.R.T + rig.stereo.T) @ R2.T
    assert np.allclose(p_1[:, 1] / p_1[:, 2], p_2[:, 1] / p_2[:, 2], atol=1e-12)
    disparity = p_1[:, 0] / p_1[:, 2] - p_2[:, 0] / p_2[:, 2]
    assert np.allclose(disparity, baseline_m / p_1[:, 2], atol=1e-12)


def _render_distorted(camera: PinholeCamera, X_WC: np.ndarray, texture: np.ndarray):
    """The plane through a distorted lens: each distorted pixel samples the ideal image at
    its undistorted position (the ideal image rendered with a margin for barrel distortion)."""
    pad = 60
    K_ideal = camera.K + np.array([[0, 0, pad], [0, 0, pad], [0, 0, 0]])
    ideal = PinholeCamera(K_ideal, np.zeros(5), camera.width + 2 * pad, camera.height + 2 * pad)
    sharp = _render_plane(ideal, X_WC, texture)
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    undistorted = cv2.undistortPointsIter(
        np.stack([u, v], -1).reshape(-1, 1, 2), camera.K, camera.distortion, None, K_ideal, criteria
    ).reshape(camera.height, camera.width, 2)
    return cv2.remap(sharp, undistorted.astype(np.float32), None, cv2.INTER_LINEAR)


def test_distorted_vertical_pair():
    """A lens with radial and tangential distortion, the other view below the reference: the
    distortion turns with the images (`rotate_camera`) and the points still lie on the plane."""
    K = np.array([[480.0, 0, 161.0], [0, 478.0, 118.0], [0, 0, 1]])
    # The product's lens (k1 -0.42, k2 0.19, SDU report) with some tangential distortion.
    camera = PinholeCamera(K, np.array([-0.42, 0.19, 0.002, -0.003, 0.0]), 320, 240)
    texture = _texture(512, 6)
    centre = X_WP[:3, 3]
    eye = np.array([0.0, 0.06, 0.0])
    X_WCj = make_pose(rotation_between([0, 0, 1], centre - eye), eye)
    cloud = pair_cloud(
        _render_distorted(camera, np.eye(4), texture),
        _render_distorted(camera, X_WCj, texture),
        camera,
        camera,
        np.eye(4),
        X_WCj,
        centre,
        0.1,
        StereoParams(),
        config=TwoViewConfig(refine_pose=False),
    )
    assert cloud.quarter_turns == 1
    assert len(cloud) > 0.5 * camera.width * camera.height
    signed_m = (cloud.points_C - centre) @ X_WP[:3, 2]
    # As without distortion: measured median |error| 0.56 mm, p95 1.7 mm; with the distortion
    # ignored (images distorted, camera ideal) 0.68 mm and 3.3 mm, the median -0.18 mm.
    assert abs(np.median(signed_m)) < 0.15e-3
    assert np.median(np.abs(signed_m)) < 0.8e-3
    assert np.percentile(np.abs(signed_m), 95) < 2.5e-3


# --- DTU scan 24 --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dtu():
    """{view: (image 400x300 RGB, mask, camera, X_WC in metres)}, working centre and radius (m).

    cameras_sphere.npz holds P = K [R | t] in millimetres (world_mat_i) and the scale matrix
    of the unit sphere around the object (scale_mat_i); decomposeProjectionMatrix gives K, R_CW
    and the camera centre in homogeneous coordinates."""
    root = shared_data(DTU)
    data = np.load(root / "cameras_sphere.npz")
    scale = data["scale_mat_0"]
    centre_m, radius_m = scale[:3, 3] / 1000.0, scale[0, 0] / 1000.0
    views = {}
    for i in DTU_VIEWS:
        K, R_CW, c_h = cv2.decomposeProjectionMatrix(data[f"world_mat_{i}"][:3])[:3]
        K = K / K[2, 2]
        K[0, 1] = 0.0  # DTU's skew is numerically zero (~1e-13 px)
        X_WC = make_pose(R_CW.T, (c_h[:3] / c_h[3]).ravel() / 1000.0)
        image = cv2.cvtColor(cv2.imread(str(root / f"images/{i:06d}.png")), cv2.COLOR_BGR2RGB)
        mask = cv2.imread(str(root / f"mask/{i:03d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        camera = PinholeCamera(K, np.zeros(5), image.shape[1], image.shape[0])
        views[i] = (
            downscaled_image(image, DOWNSCALE),
            downscaled_mask(mask, DOWNSCALE),
            downscaled_camera(camera, DOWNSCALE),
            X_WC,
        )
    return views, centre_m, radius_m


def _cloud(dtu, i, j):
    views, centre_m, radius_m = dtu
    image_i, mask_i, cam_i, X_WCi = views[i]
    image_j, _, cam_j, X_WCj = views[j]
    return pair_cloud(
        image_i, image_j, cam_i, cam_j, X_WCi, X_WCj, centre_m, radius_m, StereoParams(), mask_i
    )


def test_dtu_pairing_finds_the_arm_neighbours(dtu):
    views, centre_m, _ = dtu
    pairs = pair_views([views[i][3] for i in DTU_VIEWS], centre_m, PairingConfig(pairs_per_view=2))
    partners = {(DTU_VIEWS[p.reference], DTU_VIEWS[p.other]) for p in pairs}
    assert {(0, 1), (1, 0), (9, 10), (10, 9), (1, 9), (9, 1)} <= partners
    assert all(0.10 < p.baseline_m < 0.14 for p in pairs)  # neighbours ~120 mm apart


def test_dtu_epipolar_error_of_calibrated_pairs(dtu):
    views, _, _ = dtu
    for i, j in ((0, 1), (1, 9), (9, 10)):
        image_i, _, cam_i, X_WCi = views[i]
        image_j, _, cam_j, X_WCj = views[j]
        matches = match_features(image_i, image_j, cam_i, cam_j, EpipolarConfig())
        error = error_of(matches, cam_i, cam_j, invert(X_WCi) @ X_WCj)
        assert error.matches >= 40
        # DTU's calibration is good to a fraction of a pixel; SIFT at 400x300 to about 0.3 px.
        assert error.median_px < 0.5
        assert error.p90_px < 1.5


def test_dtu_refinement_undoes_a_pose_error(dtu):
    views, _, _ = dtu
    image_i, _, cam_i, X_WCi = views[1]
    image_j, _, cam_j, X_WCj = views[9]
    config = EpipolarConfig()
    X_true = invert(X_WCi) @ X_WCj
    matches = match_features(image_i, image_j, cam_i, cam_j, config)
    calibrated = error_of(matches, cam_i, cam_j, X_true)
    # 0.3 deg about a tilted axis and 1 mm off: what a hand-eye or arm error does to a pair.
    X_off = make_pose(
        rotation_about([1.0, 0.3, 0.2], math.radians(0.3)) @ X_true[:3, :3],
        X_true[:3, 3] + np.array([0.0, 0.7e-3, 0.7e-3]),
    )
    result = checked_pose(matches, cam_i, cam_j, X_off, config)
    assert result.before.median_px > config.max_error_px
    assert result.refined
    assert result.after.median_px < calibrated.median_px + 0.15
    translation_m, rotation_rad = pose_difference(result.X_CiCj, X_true)
    off_m, off_rad = pose_difference(X_off, X_true)
    assert rotation_rad < 0.5 * off_rad
    assert np.linalg.norm(result.X_CiCj[:3, 3]) == pytest.approx(np.linalg.norm(X_off[:3, 3]))
    # A calibrated pose stays as it is.
    kept = checked_pose(matches, cam_i, cam_j, X_true, config)
    assert not kept.refined and kept.X_CiCj is X_true


def test_dtu_pair_cloud_lies_in_the_mask_and_the_working_sphere(dtu):
    views, centre_m, radius_m = dtu
    cloud = _cloud(dtu, 0, 1)
    _, mask_i, cam_i, X_WCi = views[0]
    assert len(cloud) > 0.3 * mask_i.sum()
    assert not cloud.refined and cloud.epipolar_error.median_px < 0.5
    pixels = np.round(project_points(cam_i, cloud.points_C)).astype(int)
    assert np.mean(mask_i[pixels[:, 1], pixels[:, 0]]) > 0.99
    p_W = transform_points(X_WCi, cloud.points_C)
    assert np.mean(np.linalg.norm(p_W - centre_m, axis=1) < radius_m) > 0.99
    # Views that took no part in the pair see the points on the house too.
    for k in (9, 10):
        _, mask_k, cam_k, X_WCk = views[k]
        px = project_points(cam_k, transform_points(invert(X_WCk), p_W))
        px = np.round(px).astype(int).clip(0, [cam_k.width - 1, cam_k.height - 1])
        assert np.mean(mask_k[px[:, 1], px[:, 0]]) > 0.97


def test_dtu_vertical_and_horizontal_pairs_agree(dtu):
    """View 1 with its horizontal neighbour 0 (a half turn) and its vertical neighbour 9 (a
    quarter turn): both clouds in C_1, on the reference image's mask, on one surface."""
    views, _, _ = dtu
    _, mask, cam, _ = views[1]
    horizontal, vertical = _cloud(dtu, 1, 0), _cloud(dtu, 1, 9)
    assert (horizontal.quarter_turns, vertical.quarter_turns) == (2, 1)
    for cloud in (horizontal, vertical):
        pixels = np.round(project_points(cam, cloud.points_C)).astype(int)
        assert np.mean(mask[pixels[:, 1], pixels[:, 0]]) > 0.99
    # Per reference pixel, the depth of one cloud against the other's.
    depths = []
    for cloud in (horizontal, vertical):
        pixels = np.round(project_points(cam, cloud.points_C)).astype(int)
        z = np.full((cam.height, cam.width), np.nan)
        z[pixels[:, 1], pixels[:, 0]] = cloud.points_C[:, 2]
        depths.append(z)
    both = np.isfinite(depths[0]) & np.isfinite(depths[1])
    assert both.sum() > 0.3 * mask.sum()
    dz_m = (depths[1] - depths[0])[both]
    # A disparity pixel is ~5 mm of depth at 0.65 m at 400x300. Measured: no bias (median
    # -0.1 mm), median |dz| 1.6 mm (0.3 px of SGBM noise on real images at this scale).
    assert abs(np.median(dz_m)) < 1.0e-3
    assert np.median(np.abs(dz_m)) < 2.5e-3

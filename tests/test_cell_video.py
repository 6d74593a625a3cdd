"""The static camera's video of the cell: intruders where their 3D path projects, robot masks at
the measured joints, frame times along trajectories, and path validation."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.stereo.camera_model import project_points
from robots.drivers.interfaces import JointTrajectory
from robots.models.camera_tool import tool_visual_boxes
from robots.models.kinematics import Kinematics
from robots.simulation.cell import HOME_Q
from robots.simulation.cell_video.intruders import (
    MONITORED_VOLUME,
    IntruderPath,
    default_intruder_paths,
)
from robots.simulation.cell_video.video import CellVideo

# Sensor noise is 2 grey levels: a difference of two frames above 20 is 7 sigma, never noise.
CHANGED_GREY = 20
FPS = 15.0


@pytest.fixture(scope="module")
def paths():
    # Far enough apart that the first has gone before the second comes.
    return default_intruder_paths([0.5, 8.0], seed=5)


@pytest.fixture(scope="module")
def video(vase_sim, paths):
    return CellVideo.from_simulation(vase_sim, paths=paths, fps=FPS)


def _project(video: CellVideo, p_W: np.ndarray, right: bool = False) -> np.ndarray:
    X_WS = video.X_WS @ video.stereo.X_CR if right else video.X_WS
    cam = video.stereo.right if right else video.stereo.left
    return project_points(cam, transform_points(invert(X_WS), p_W[None]))[0]


def _axis_distance_px(
    video: CellVideo, path: IntruderPath, t_s: float, right: bool, vu: np.ndarray
) -> np.ndarray:
    """Pixels' distance (px) outside the forearm's projected silhouette: the projected axis
    segment widened by the projected radius at its nearer end."""
    p_W = path.position_W(t_s)
    ends_W = [p_W + s * 0.5 * path.length_m * path.direction_W for s in (-1.0, 1.0)]
    a, b = (_project(video, e, right) for e in ends_W)
    X_WS = video.X_WS @ video.stereo.X_CR if right else video.X_WS
    depth_m = transform_points(invert(X_WS), np.array(ends_W))[:, 2]
    radius_px = video.stereo.left.focal_px * path.radius_m / depth_m.min()
    uv = vu[:, ::-1].astype(float)
    d = b - a
    t = np.clip((uv - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(uv - (a + t[:, None] * d), axis=1) - radius_px


def _changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a.astype(int) - b.astype(int)) > CHANGED_GREY


def test_intruder_appears_where_its_path_projects_only_while_present(video, paths, vase_sim):
    q_true = HOME_Q + vase_sim.truth.joint_offsets_rad
    empty = video.frame(0.1, q_true)
    assert not empty.intruder_present
    for path in paths:
        t_stop = path.start_s + path.travel_s + 0.5 * path.dwell_s
        assert not path.present(path.start_s) and not path.present(path.end_s)
        assert path.present(t_stop) and path.position_W(path.end_s + 0.01) is None
        # It enters and leaves out of the camera's sight.
        assert not video.intruder_mask(path.start_s, q_true).any()
        seen = video.frame(t_stop, q_true)
        assert seen.intruder_present
        p_W = path.position_W(t_stop)
        np.testing.assert_allclose(seen.intruders_p_W[0], p_W, atol=1e-12)
        np.testing.assert_allclose(p_W, path.stop_m, atol=1e-9)
        for right in (False, True):
            changed = _changed(
                seen.right if right else seen.left, empty.right if right else empty.left
            )
            # A 90 mm forearm 0.6-1.7 m away: hundreds to thousands of pixels, fewer when it
            # points at the camera or the arm hides some of it.
            assert changed.sum() > 500
            # The changed pixels lie along the projected axis, within the projected radius
            # (+ 3 px for the 0.5 px rendering offsets and the ends' perspective).
            band_px = _axis_distance_px(video, path, t_stop, right, np.argwhere(changed))
            assert np.mean(band_px < 3.0) > 0.97
        truth_mask = video.intruder_mask(t_stop, q_true)
        left_changed = _changed(seen.left, empty.left)
        assert left_changed[truth_mask].mean() > 0.5
        # The label render has no anti-aliasing: the grey edge pixels around the silhouette
        # change too (~5 % of a small forearm 1.6 m away), within 1 px of the truth mask.
        truth_edge = cv2.dilate(truth_mask.view(np.uint8), np.ones((3, 3), np.uint8)) > 0
        assert truth_edge[left_changed].mean() > 0.99
    # Before it enters and after it has left the picture is the empty cell (noise only).
    for t_s in (paths[0].start_s - 0.2, paths[0].end_s + 0.1):
        if any(p.position_W(t_s) is not None for p in paths):
            continue
        assert _changed(video.frame(t_s, q_true).left, empty.left).sum() < 5


def test_robot_mask_covers_the_arm_at_measured_joints_and_follows_it(video, vase_sim):
    offsets = vase_sim.truth.joint_offsets_rad
    kinematics = Kinematics()
    q_a = HOME_Q
    q_b = HOME_Q + np.array([0.5, 0.2, -0.3, 0.0, 0.3, 0.0])
    masks = []
    for q in (q_a, q_b):
        mask = video.robot_mask(q, margin_px=0)
        u, v = np.round(_project(video, kinematics.X_WF(q)[:3, 3])).astype(int)
        assert mask[v, u]
        masks.append(mask)
    overlap = (masks[0] & masks[1]).sum() / (masks[0] | masks[1]).sum()
    assert overlap < 0.8  # the base column stays, the arm above it moves
    u, v = np.round(_project(video, kinematics.X_WF(q_b)[:3, 3])).astype(int)
    assert not masks[0][v, u]
    # Every pixel that changes because the arm moved is the arm's, before or after the move;
    # the 4 px margin covers the 0.01 deg encoder offsets (< 0.2 mm, a fraction of a pixel).
    before = video.frame(0.1, q_a + offsets).left
    after = video.frame(0.1, q_b + offsets).left
    changed = _changed(before, after)
    assert changed.sum() > 2000
    covered = video.robot_mask(q_a, 4) | video.robot_mask(q_b, 4)
    assert covered[changed].mean() > 0.999
    wider = video.robot_mask(q_a, 12)
    assert wider.sum() > video.robot_mask(q_a, 4).sum() > masks[0].sum()
    # The object hangs above this view: only its rod may show, a thin sliver.
    assert video.object_mask(8).mean() < 0.05


def test_frames_along_a_trajectory_keep_the_clock_and_show_the_motion(video, vase_sim):
    offsets = vase_sim.truth.joint_offsets_rad
    q_end = HOME_Q + np.array([0.4, 0.0, 0.0, 0.0, 0.0, 0.0])
    times = np.linspace(0.0, 1.0, 11)
    trajectory = JointTrajectory(times, HOME_Q + np.outer(times, q_end - HOME_Q))
    t0 = 20.0
    frames = list(video.frames_along(trajectory, t0_s=t0))
    assert len(frames) == 15
    np.testing.assert_allclose([f.t_s for f in frames], t0 + np.arange(15) / FPS, atol=1e-9)
    for f in frames:
        np.testing.assert_allclose(f.q_measured_rad[0], HOME_Q[0] + 0.4 * (f.t_s - t0), atol=1e-9)
        np.testing.assert_allclose(f.q_true_rad - f.q_measured_rad, offsets, atol=1e-12)
    assert video.clock_s == pytest.approx(t0 + 1.0)
    moved = _changed(frames[0].left, frames[-1].left)
    assert moved.sum() > 1000
    assert video.robot_mask(frames[0].q_measured_rad, 4)[moved].mean() > 0.3
    rest = list(video.frames_at_rest(q_end, 0.5))
    assert len(rest) == 8 and rest[0].t_s == pytest.approx(t0 + 1.0)
    assert rest[1].t_s - rest[0].t_s == pytest.approx(1 / FPS)
    np.testing.assert_allclose(rest[0].q_measured_rad, q_end)
    assert video.clock_s == pytest.approx(t0 + 1.0 + 8 / FPS)
    # The final pose of the trajectory is the first frame at rest: the arm no longer moves.
    assert _changed(rest[0].left, rest[-1].left).sum() < 5
    assert not np.array_equal(rest[0].left, rest[1].left)  # each frame has its own noise


def test_default_paths_differ_by_seed_and_start_and_stay_in_view(video):
    a = default_intruder_paths([1.0, 5.0, 9.0, 13.0], seed=1)
    b = default_intruder_paths([1.0, 5.0, 9.0, 13.0], seed=2)
    assert a == default_intruder_paths([1.0, 5.0, 9.0, 13.0], seed=1)
    assert [p.start_s for p in a] == [1.0, 5.0, 9.0, 13.0]
    for paths in (a, b):
        directions = np.array([p.direction_W for p in paths])
        # Consecutive paths come from different sides of the cell.
        assert np.all(np.sum(directions[1:] * directions[:-1], axis=1) < 0.9)
        for p in paths:
            assert MONITORED_VOLUME.contains(p.stop_m)
            assert 0.5 <= p.speed_m_s <= 1.0
            assert not p.present(p.start_s) and p.present(p.start_s + p.travel_s)
            u, v = _project(video, np.asarray(p.stop_m))
            assert 0 <= u < 640 and 0 <= v < 480
    assert all(not np.allclose(p.stop_m, q.stop_m) for p, q in zip(a, b, strict=True))


@pytest.mark.parametrize(
    ("fields", "named"),
    [
        ({"start_s": 1.0, "speed_m_s": -0.5}, "speed_m_s"),
        ({"start_s": math.nan}, "start_s"),
        ({"start_s": 0.0, "entry_m": (0.3, 0.0, 0.5)}, "entry_m"),
        ({"start_s": 0.0, "stop_m": (0.3, 2.0, 0.5)}, "stop_m"),
        ({"start_s": 0.0, "dwell_s": math.inf}, "dwell_s"),
    ],
)
def test_bad_paths_are_one_line_user_errors(fields, named):
    with pytest.raises(ScannerError) as error:
        IntruderPath(**fields)
    assert named in str(error.value) and "\n" not in str(error.value)


def test_bad_times_are_user_errors(video):
    with pytest.raises(ScannerError, match="start_times_s"):
        default_intruder_paths([1.0, math.nan], seed=0)
    with pytest.raises(ScannerError, match="duration_s"):
        video.frames_at_rest(HOME_Q, math.nan)
    with pytest.raises(ScannerError, match="fps"):
        video.frames_at_rest(HOME_Q, 1.0, fps=-15)
    with pytest.raises(ScannerError, match="t_s"):
        video.frame(math.nan, HOME_Q)


def test_window_rendering_matches_whole_image_rendering(vase_sim, paths, video):
    """Frames render only the window holding the arm and the forearms over a background
    rendered once: the picture must be the whole render's, but for a few anti-aliased
    edge pixels where the rasteriser splits a triangle edge differently."""
    sim = vase_sim
    whole = CellVideo(
        sim.workcell.config, sim.object_mesh, sim.truth, paths=paths, fps=FPS, roi_rendering=False
    )
    q_true = HOME_Q + np.array([0.3, 0.1, -0.2, 0.0, 0.2, 0.0])
    path = paths[0]
    for t_s in (0.1, path.start_s + path.travel_s):
        a, b = video.frame(t_s, q_true), whole.frame(t_s, q_true)
        for x, y in ((a.left, b.left), (a.right, b.right)):
            assert _changed(x, y).mean() < 0.001


def test_tool_mask_is_the_dark_camera_tool_in_both_images(video, vase_sim):
    kinematics = Kinematics()
    q = HOME_Q + np.array([0.3, 0.1, -0.2, 0.0, 0.2, 0.0])
    frame = video.frame(0.1, q + vase_sim.truth.joint_offsets_rad)
    X_WF = kinematics.X_WF(q)
    # The centre of the tool's body, in front of its bracket.
    p_W = X_WF[:3, :3] @ np.array(tool_visual_boxes()[1].p_FB) + X_WF[:3, 3]
    robot = video.robot_mask(q, 2)
    areas = []
    for right, image in ((False, frame.left), (True, frame.right)):
        side = "right" if right else "left"
        mask = video.tool_mask(q, side, 0)
        u, v = np.round(_project(video, p_W, right)).astype(int)
        assert mask[v, u]
        # The tool (0.15 grey) is the darkest thing on the arm; the links are 0.5-0.8.
        assert np.median(image[mask]) < 60
        ring = video.tool_mask(q, side, 4) & ~video.tool_mask(q, side, 1)
        assert np.median(image[ring]) > 60
        areas.append(mask.sum())
        if not right:
            assert robot[mask].all() and mask.sum() < 0.3 * robot.sum()
    # A 157 x 47 mm box about 0.9 m away: a few thousand pixels in either image.
    assert min(areas) > 1000 and max(areas) < 2 * min(areas)
    assert not np.array_equal(video.tool_mask(q, "left", 0), video.tool_mask(q, "right", 0))
    with pytest.raises(ScannerError, match="side"):
        video.tool_mask(q, "top", 0)

"""The end-effector tracker on synthetic stereo frames (tests/monitor_frames.py): a textured disc
moving at constant velocity through known 3D positions stands in for the tool."""

import numpy as np
import pytest

from reconstruction.errors import ScannerError
from scanner.monitor.ee_tracker import (
    EndEffectorTracker,
    TrackerConfig,
    TrackEstimate,
    tracking_errors,
)
from tests.monitor_frames import Disc, Scene

FPS = 15.0
P0_W = np.array([0.6, 0.35, 0.8])  # 1.4 m from the rig
V_W = np.array([0.1, -0.25, 0.08])  # 0.28 m/s, 19 mm per frame
TOOL_RADIUS_M = 0.05


def _true(k: int) -> np.ndarray:
    return P0_W + V_W * k / FPS


def _track(scene, frames, seen_offset_W=lambda k: np.zeros(3), config=None):
    tracker = EndEffectorTracker(scene.rig, config)
    out = []
    for k in range(frames):
        p_seen = _true(k) + seen_offset_W(k)
        left, right, _, _ = scene.frame([Disc(tuple(p_seen), TOOL_RADIUS_M, grey=200.0)])
        out.append(tracker.update(left, right, k / FPS, _true(k)))
    return out


@pytest.fixture(scope="module")
def scene():
    return Scene(seed=5)


@pytest.fixture(scope="module")
def steady(scene):
    return _track(scene, 40)


def test_first_measurement_with_the_third_frame(steady):
    assert [e.measured for e in steady[:2]] == [False, False]
    assert steady[0].p_W is None
    assert all(e.measured for e in steady[2:])


def test_position_and_velocity_converge_to_the_truth(steady):
    later = steady[15:]
    errors = tracking_errors(
        later, [_true(k) for k in range(15, 40)], np.tile(V_W, (len(later), 1))
    )
    print(*errors.lines(), sep="\n")
    # Disparity 115-140 px: a blob centroid uneven by 0.5 px is 5 mm of depth, and the
    # estimate is extrapolated a frame ahead of its last measurement.
    assert errors.rms_position_m < 0.006
    assert errors.max_position_m < 0.02
    # 5 mm of measurement noise differentiated at 15 fps, smoothed by the filter.
    assert errors.rms_velocity_mps < 0.05
    assert not any(e.disagreement for e in steady)


def test_step_offset_from_forward_kinematics_is_flagged(scene):
    step = 20
    # A collision pushes the tool 6 cm sideways; forward kinematics does not know.
    offset = np.array([0.0, 0.06, 0.0])
    estimates = _track(scene, 32, lambda k: offset if k >= step else np.zeros(3))
    assert not any(e.disagreement for e in estimates[:step])
    flagged = next(k for k, e in enumerate(estimates) if e.disagreement)
    # Measurements lag one frame, the filter a few more, then n frames in a row.
    config = TrackerConfig()
    assert flagged <= step + 1 + config.disagreement_frames + 3
    assert all(e.disagreement for e in estimates[flagged:])
    assert estimates[-1].error_to_fk_m == pytest.approx(0.06, abs=0.015)


def test_tracking_errors_against_known_values():
    estimates = [
        TrackEstimate(0.0, None, None, False, None, False),
        TrackEstimate(0.1, np.array([0.003, 0.0, 0.0]), np.array([0.0, 0.01, 0.0]), True, 0, False),
        TrackEstimate(0.2, np.array([0.0, 0.004, 0.0]), np.array([0.0, 0.0, 0.0]), True, 0, False),
    ]
    errors = tracking_errors(estimates, np.zeros((3, 3)), np.zeros((3, 3)))
    assert errors.frames == 2
    assert errors.rms_position_m == pytest.approx(np.sqrt((0.003**2 + 0.004**2) / 2))
    assert errors.max_position_m == pytest.approx(0.004)
    assert errors.rms_velocity_mps == pytest.approx(0.01 / np.sqrt(2))


@pytest.mark.parametrize(
    ("field", "value"),
    [("disagreement_m", 0.0), ("disagreement_frames", 0), ("search_window_px", 2)],
)
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ScannerError, match=f"tracker.{field}"):
        TrackerConfig(**{field: value})

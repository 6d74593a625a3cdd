"""Hand-eye refinement weighting: the images against the robot-pose prior, on the simulator's
error model without rendering (the default stations, encoder zero offsets, the true cameras,
Gaussian corner noise), so every error is known and the test takes seconds."""

import math

import numpy as np
import pytest

from planners.ik import camera_pose, ik_camera, rig_centre_offset
from reconstruction.calibration.boards import BoardSpec, Detection
from reconstruction.calibration.eye_in_hand import calibrate_hand_eye
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.transforms import invert, pose_difference, transform_points
from reconstruction.stereo.camera_model import StereoDesign, project_points
from robots.arms.rx60 import RX60, fk_flange, rx60_arm
from robots.models.calibration_board import BoardPlacement
from robots.models.camera_tool import nominal_X_FC
from robots.simulation.truth import ErrorModel, sample_truth
from scanner.calibrate.stations import StationConfig, plan_stations

BOARD = BoardSpec("chessboard", 10, 7, 0.02)
# findChessboardCornersSB on the simulator's renders: ~0.03 px per coordinate.
CORNER_NOISE_PX = 0.03
HOME_Q = np.array([0.0, -0.4, 2.3, 0.0, 0.8, 0.0])  # the simulated arm's start
SEEDS = (0, 1, 2)


@pytest.fixture(scope="module")
def stations():
    stereo = StereoDesign().stereo_camera()
    X_FC = nominal_X_FC(stereo.baseline_m)
    X_MC = rig_centre_offset(stereo.X_CR)
    arm = rx60_arm()
    plan = plan_stations(
        StationConfig(),
        BOARD,
        BoardPlacement().X_WB(BOARD),
        stereo,
        X_FC,
        lambda viewpoint: ik_camera(arm, camera_pose(viewpoint, X_MC), X_FC),
        HOME_Q,
    )
    return [s.q for s in plan.stations]


def _observations(stations, seed: int):
    """Board corners as the true arm (encoder offsets) and true X_FC see them; X_WF as the
    controller reports it. Returns the observations, the cameras and the true X_FC."""
    stereo = StereoDesign().stereo_camera()
    truth = sample_truth(ErrorModel(seed=seed), nominal_X_FC(stereo.baseline_m), stereo, np.eye(4))
    X_WB = BoardPlacement().X_WB(BOARD)
    robot, p_B = RX60(), BOARD.object_points()
    rng = np.random.default_rng(seed)
    out = []
    for k, q in enumerate(stations):
        X_WC = fk_flange(robot, q + truth.joint_offsets_rad) @ truth.X_FC
        p_C = transform_points(invert(X_WC) @ X_WB, p_B)
        views = []
        for camera, X_SC in ((stereo.left, np.eye(4)), (stereo.right, invert(stereo.X_CR))):
            pixels = project_points(camera, transform_points(X_SC, p_C))
            pixels += rng.normal(0.0, CORNER_NOISE_PX, pixels.shape)
            views.append(Detection(np.arange(len(p_B)), pixels))
        out.append(PoseObservation(f"{k:04d}", fk_flange(robot, q), *views))
    return out, stereo, truth.X_FC


@pytest.fixture(scope="module")
def results(stations):
    """Per seed: errors (m, rad) of ours, of the configured-sigma refinement, of each method."""
    rows = []
    for seed in SEEDS:
        observations, stereo, X_FC_true = _observations(stations, seed)
        ours = calibrate_hand_eye(BOARD, observations, stereo)
        configured = calibrate_hand_eye(
            BOARD, observations, stereo, CalibrationSettings(pixel_sigma_from_data=False)
        )
        errors = {"ours": pose_difference(ours.X_FC, X_FC_true)}
        errors["configured"] = pose_difference(configured.X_FC, X_FC_true)
        errors |= {name: pose_difference(X, X_FC_true) for name, X in ours.opencv.items()}
        rows.append((ours, configured, errors))
    return rows


def test_the_image_noise_is_measured(results):
    for ours, configured, _ in results:
        # The first pass leaves a little of the robot's errors in the residuals.
        assert ours.pixel_sigma_px == pytest.approx(CORNER_NOISE_PX, rel=0.15)
        assert configured.pixel_sigma_px == CalibrationSettings().pixel_sigma_px
        assert ours.outliers == []


def test_refined_hand_eye_beats_every_opencv_method_on_average(results):
    mean = {
        name: np.mean([errors[name] for _, _, errors in results], axis=0) for name in results[0][2]
    }
    methods = [name for name in mean if name not in ("ours", "configured")]
    assert len(methods) >= 4
    for name in methods:
        assert mean["ours"][0] <= mean[name][0], name
        assert mean["ours"][1] <= mean[name][1], name
    # Weighed with 0.3 px the images count a hundred times too little and the robot's errors
    # move X_FC: twice the translation error (0.08 against 0.04 mm here).
    assert mean["ours"][0] < 0.6 * mean["configured"][0]
    assert mean["ours"][0] < 0.06e-3 and mean["ours"][1] < math.radians(0.01)


def test_without_robot_corrections_the_configured_sigma_stays(stations):
    observations, stereo, _ = _observations(stations, 0)
    exact = CalibrationSettings(robot_translation_sigma_m=0.0, robot_rotation_sigma_rad=0.0)
    result = calibrate_hand_eye(BOARD, observations, stereo, exact)
    assert result.pixel_sigma_px == exact.pixel_sigma_px

"""The robot's own errors on any serial chain: an arm file's arm hands the calibration the joint
chain of its model, the calibration recovers a UR5e's encoder offsets on it, and a calibration's
robot correction serves scans of its own arm only."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from reconstruction.calibration.eye_in_hand import calibrate_hand_eye
from reconstruction.calibration.file import Calibration, RobotCorrection, save_calibration
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import pose_difference
from robots.arms.default import DEFAULT_ARM, arm_of
from robots.models.kinematics import corrected_kinematics
from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.sigma_check import render_free_observations
from scanner.configs.scan import ScanConfig

ROOT = Path(__file__).resolve().parents[1]
UR5E_FILE = str(ROOT / "scanner" / "configs" / "arms" / "ur5e.yaml")
IIWA_FILE = str(ROOT / "scanner" / "configs" / "arms" / "iiwa14.yaml")
# The chain is the model's own transforms: it agrees with Drake's FK to rounding.
CHAIN_FK_TOL_M = 1e-12
# The default error model's encoder offsets are 0.01 deg per joint; recovered to half of that
# (the RX60's bound in test_calibration_quality.py), and within 3 of their reported sigmas.
OFFSET_TOL_DEG = 0.005


@pytest.mark.parametrize("arm_file", [UR5E_FILE, IIWA_FILE])
def test_the_joint_chain_is_the_models_kinematics(arm_file):
    arm = arm_of(arm_file)
    chain = arm.error_model()
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(arm.lower, arm.upper)
        X_WF = arm.X_WF(q).GetAsMatrix4()
        assert np.allclose(chain.flange_pose(q, np.zeros(chain.size)), X_WF, atol=CHAIN_FK_TOL_M)
    assert chain.arm_name == arm.name and chain.joint_count == arm.joint_count


def test_a_link_length_correction_stretches_the_link_along_itself():
    """The UR5e's upper arm (0.425 m before the elbow) 1 mm longer moves the flange by 1 mm at
    the zero pose, where the arm is stretched out straight along that link."""
    model = arm_of(UR5E_FILE).error_model()
    p = np.zeros(model.size)
    p[model.joint_count + model.length_keys.index("elbow_joint_length_m")] = 1e-3
    q = np.zeros(model.joint_count)
    moved_m = pose_difference(model.flange_pose(q, p), model.flange_pose(q, 0 * p))[0]
    assert moved_m == pytest.approx(1e-3, abs=1e-12)


@pytest.fixture(scope="module")
def ur5e_observations():
    """8 render-free stations of a UR5e calibration (the default error model, seed 0: encoder
    offsets of 0.01 deg per joint); the planner draws 24 candidates, not 800, to stay cheap."""
    config = CalibrateConfig(robot=UR5E_FILE)
    config = replace(config, stations=replace(config.stations, count=8, candidates=24))
    return config, render_free_observations(config, [0])[0]


def test_a_ur5es_encoder_offsets_are_recovered_on_its_chain(ur5e_observations):
    config, (observations, _, offsets_true) = ur5e_observations
    stereo = config.camera.stereo_camera()
    model = arm_of(UR5E_FILE).error_model()
    he = calibrate_hand_eye(config.board, observations, stereo, arm=model, robot_offsets=True)
    e = he.robot_errors
    joints = [k for k in e.estimated if k < model.joint_count]
    assert e.kept and joints == [1, 2, 3, 4], e.note  # measured: all four, 0.0016 deg at most
    assert "about the base axis" in e.not_observable[0]
    assert "about its own axis" in e.not_observable[5]
    error = np.abs(e.params[joints] - offsets_true[joints])
    assert np.all(np.degrees(error) < OFFSET_TOL_DEG), np.degrees(error)
    assert np.all(error < 3 * e.sigma[joints]), (error, e.sigma[joints])
    assert e.held_out_px_with < e.held_out_px_without
    assert e.arm_name == "ur5e" and len(e.joint_offsets_rad) == 6


def _calibration_file(folder: Path, robot: RobotCorrection) -> Path:
    stereo = ScanConfig().camera.stereo_camera()
    calibration = Calibration(np.eye(4), stereo, stereo.left, robot=robot)
    return save_calibration(calibration, folder / f"{robot.arm}.yaml")


def test_a_robot_correction_serves_its_own_arm_only(tmp_path):
    from scanner.scan.world import software_kinematics

    ur5e = arm_of(UR5E_FILE)
    offsets = (0.0, 1e-4, 0.0, 0.0, 0.0, 0.0)
    correction = RobotCorrection(offsets, {"elbow_joint_length_m": 2e-4}, "ur5e")
    path = _calibration_file(tmp_path, correction)
    config = replace(ScanConfig(), robot=UR5E_FILE, calibration_file=str(path))
    X_WF = software_kinematics(config)
    q = np.array(ur5e.home_q)
    chain = ur5e.error_model()
    expected = chain.flange_pose(q, np.array([*offsets, 2e-4, 0, 0, 0]))
    assert np.allclose(X_WF(q), expected, atol=1e-15)
    assert pose_difference(X_WF(q), ur5e.X_WF(q).GetAsMatrix4())[0] > 1e-5
    with pytest.raises(ScannerError, match="^calibration_file: .* arm ur5e's, this arm is rx60"):
        software_kinematics(replace(config, robot="rx60"))
    rx60 = RobotCorrection(offsets, {"forearm_m": 1e-4})  # a file of before arms were named
    with pytest.raises(ScannerError, match="^x: .* arm rx60's, this arm is ur5e"):
        corrected_kinematics(ur5e, rx60, "x")
    assert np.allclose(
        corrected_kinematics(DEFAULT_ARM, rx60, "x")(q),
        DEFAULT_ARM.error_model().flange_pose(q, np.array([*offsets, 0, 0, 0, 1e-4, 0])),
        atol=1e-15,
    )
    with pytest.raises(ScannerError, match="does not fit arm ur5e .* 6 joint offsets"):
        corrected_kinematics(ur5e, RobotCorrection((0.0,) * 7, {}, "ur5e"), "x")


def test_chain_pose_with_offsets_is_the_pose_at_the_true_joints():
    arm = arm_of(IIWA_FILE)
    chain = arm.error_model()
    q = np.array(arm.home_q)
    offsets = np.full(arm.joint_count, 1e-3)
    p = np.concatenate([offsets, np.zeros(chain.size - arm.joint_count)])
    assert np.allclose(
        chain.flange_pose(q, p), arm.X_WF(q + offsets).GetAsMatrix4(), atol=CHAIN_FK_TOL_M
    )

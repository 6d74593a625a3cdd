"""A calibration that found the arm's own errors makes the scan's flange poses better: the file
carries them, a scan computes its poses from the corrected arm, and a reconstruction with such a
calibration applies them to captures made without it."""

import re
from dataclasses import replace

import numpy as np
import pytest
import yaml

from reconstruction.calibration.file import (
    Calibration,
    RobotCorrection,
    calibration_to_dict,
    load_calibration,
    save_calibration,
)
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import pose_difference
from robots.arms.default import DEFAULT_ARM
from robots.arms.rx60 import RX60
from robots.models.kinematics import Kinematics, corrected_kinematics
from robots.simulation.cell import HOME_Q
from robots.simulation.truth import ErrorModel, sample_truth
from scanner.configs.scan import ScanConfig
from scanner.scan.world import software_kinematics


def _calibration(robot: RobotCorrection | None) -> Calibration:
    stereo = ScanConfig().camera.stereo_camera()
    return Calibration(np.eye(4), stereo, stereo.left, robot=robot)


def test_the_file_carries_the_robot_correction(tmp_path):
    robot = RobotCorrection((0.0, 1e-4, -2e-4, 3e-5, 0.0, 0.0), {"upper_arm_m": 2e-4})
    path = save_calibration(_calibration(robot), tmp_path / "calibration.yaml")
    again = load_calibration(path)
    assert again.robot == robot
    assert load_calibration(save_calibration(_calibration(None), tmp_path / "b.yaml")).robot is None


@pytest.mark.parametrize(
    "robot, message",
    [
        ({"joint_offsets_rad": []}, "robot.joint_offsets_rad: expected one offset per joint"),
        ({"joint_offsets_rad": [0.1] * 6}, "within +-1 deg"),
        (
            {"joint_offsets_rad": [0.0] * 6, "link_length_corrections_m": {"forearm_m": 0.05}},
            "robot.link_length_corrections_m: expected corrections within +-5 mm",
        ),
        ("offsets", "robot: expected a mapping"),
    ],
)
def test_a_bad_robot_section_is_one_line_naming_the_field(tmp_path, robot, message):
    d = calibration_to_dict(_calibration(None))
    d["robot"] = robot
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(ScannerError, match=re.escape(message)) as e:
        load_calibration(path)
    assert str(e.value).startswith(f"{path}: robot") and "\n" not in str(e.value)


def test_unknown_link_names_are_refused():
    with pytest.raises(ValueError, match="not link lengths of the RX60: wrist_m"):
        RX60().with_length_corrections({"wrist_m": 1e-4})


def test_a_scan_with_the_correction_computes_poses_closer_to_the_truth(tmp_path):
    """The simulator's arm turns its joints by the true encoder offsets; a calibration file
    with those offsets makes the scan's X_WF(reported q) the true flange pose, without it the
    pose is off by the offsets' effect (about 0.1 mm)."""
    stereo = ScanConfig().camera.stereo_camera()
    truth = sample_truth(ErrorModel(seed=3), np.eye(4), stereo, np.eye(4))
    true_pose = Kinematics().X_WF
    offsets = tuple(truth.joint_offsets_rad)
    path = save_calibration(_calibration(RobotCorrection(offsets)), tmp_path / "calibration.yaml")
    corrected = software_kinematics(replace(ScanConfig(), calibration_file=str(path)))
    nominal = software_kinematics(ScanConfig())
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = np.asarray(HOME_Q) + rng.uniform(-0.5, 0.5, 6)
        X_true = true_pose(q + truth.joint_offsets_rad)
        before = pose_difference(nominal(q), X_true)[0]
        after = pose_difference(corrected(q), X_true)[0]
        assert before > 2e-5 and after < 1e-9


def test_corrected_link_lengths_move_the_flange_as_the_closed_form_arm():
    from robots.arms.rx60 import arm_model, rx60_arm

    arm = arm_model()
    p = np.zeros(arm.size)
    p[:6] = [1e-4, -2e-4, 3e-4, 0.0, 1e-4, 0.0]
    p[6 + list(arm.length_keys).index("forearm_m")] = 4e-4
    X_WF = corrected_kinematics(
        rx60_arm(), RobotCorrection(tuple(p[:6]), {"forearm_m": 4e-4}), "calibration_file"
    )
    q = np.asarray(HOME_Q, float) + 0.2
    assert np.allclose(X_WF(q), arm.flange_pose(q, p), atol=1e-12)


def test_a_reconstruction_with_the_correction_recomputes_the_capture_poses(tiny_scan):
    from scanner.scan_dir.manifest import open_scan

    scan = open_scan(tiny_scan.scan_dir)
    index = scan.store.captured_indices()[0]
    capture = scan.store.read_capture(index)
    assert np.array_equal(scan.X_WF(capture), capture.X_WF)
    offsets = (0.0, 1e-3, 0.0, 0.0, 0.0, 0.0)
    correction = RobotCorrection(offsets, {})
    corrected = replace(scan, flange_pose=corrected_kinematics(DEFAULT_ARM, correction, "x"))
    expected = Kinematics().X_WF(capture.q_rad + np.array(offsets))
    assert np.allclose(corrected.X_WF(capture), expected, atol=1e-12)
    assert pose_difference(corrected.X_WF(capture), capture.X_WF)[0] > 1e-4

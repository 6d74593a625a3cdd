"""A scan configuration names its arm (`robot:`, `--robot`), the scan directory records it, and a
simulated scan runs with an arm from an arm file (the UR5e) as with the RX60."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from robots.arms.default import arm_of
from scanner.configs.scan import ScanConfig, load_scan_config, with_overrides
from scanner.scan_dir.manifest import open_scan
from tests.in_process import scanner
from tests.tiny_arm import write_tiny_arm
from tests.tiny_scan import TINY_SCAN

ROOT = Path(__file__).resolve().parents[1]
UR5E_FILE = ROOT / "scanner" / "configs" / "arms" / "ur5e.yaml"
# The default cell hangs the object 1 m up, out of the UR5e's 0.85 m reach: the UR5e scan hangs
# a 0.1 m object low in front of it and looks from 0.3 m.
UR5E_SCAN = {
    **TINY_SCAN,
    "robot": str(UR5E_FILE),
    "cell": {"object_center_m": [0.45, 0.0, 0.45], "object_size_m": 0.1},
    # Fewer view candidates than the tiny scan's 200: each is an IK request, which the UR5e
    # answers numerically (about 0.1 s), where the RX60 has its closed form. 20 still give
    # the 5 views (40 made the candidates' IK 45 % of this scan's time).
    "views": {**TINY_SCAN["views"], "radius_m": 0.3, "candidates": 20},
}
# The captures' flange poses are the UR5e's FK at the reported joints, to rounding.
FLANGE_TOL_M = 1e-9
# The tiny scan's camera (330 px focal length) resolves 0.9 mm a pixel at 0.3 m: a model within a
# few pixels of the truth where it was seen shows the UR5e's poses placed the views.
CHAMFER_OBSERVED_MAX_MM = 5.0


def write_config(folder: Path, data: dict) -> Path:
    path = folder / "scan.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_default_robot_is_the_rx60():
    assert ScanConfig().robot == "rx60"
    assert arm_of(ScanConfig().robot).name == "rx60"


def test_an_arm_file_is_read_from_the_configuration_folder(tmp_path):
    shutil.copy(UR5E_FILE, tmp_path / "ur5e.yaml")
    text = (tmp_path / "ur5e.yaml").read_text()
    # The copy's model paths are relative to its new folder: point them at the repository's.
    models = str(ROOT / "robots" / "arms" / "models")
    (tmp_path / "ur5e.yaml").write_text(text.replace("../../../robots/arms/models", models))
    config = load_scan_config(write_config(tmp_path, {"robot": "ur5e.yaml"}))
    assert Path(config.robot) == tmp_path / "ur5e.yaml"
    assert arm_of(config.robot).name == "ur5e"


@pytest.mark.parametrize(
    "robot, needle",
    [
        ("kuka", "robot: expected 'rx60' or the path of an arm file, got 'kuka'"),
        ("missing.yaml", "robot: expected 'rx60' or the path of an arm file"),
        ("broken.yaml", "robot: "),
    ],
)
def test_a_bad_robot_is_refused_naming_the_field(robot, needle, tmp_path):
    (tmp_path / "broken.yaml").write_text("name: broken\n")
    with pytest.raises(ScannerError, match=needle) as e:
        load_scan_config(write_config(tmp_path, {"robot": robot}))
    assert "\n" not in str(e.value)
    with pytest.raises(ScannerError, match="^--robot: ") as e:
        with_overrides(ScanConfig(), robot=str(tmp_path / robot))
    assert "\n" not in str(e.value)


def test_scan_refuses_a_bad_robot_flag_in_one_line(tmp_path, capfd):
    r = scanner(capfd, "scan", "--robot", tmp_path / "no-arm.yaml", "--out", tmp_path / "o")
    assert r.returncode == 2
    assert "--robot: expected 'rx60' or the path of an arm file" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_scan_directory_of_the_fixed_rx60_still_reads(tiny_scan, tmp_path):
    """Scans written before the arm was configurable: no `robot` in their configuration and the
    manifest's robot entry {model: staubli_rx60, urdf_sha256}."""
    scan_dir = tmp_path / "old"
    shutil.copytree(tiny_scan.scan_dir, scan_dir)
    manifest_path = scan_dir / "scan.yaml"
    manifest = yaml.safe_load(manifest_path.read_text())
    assert manifest["robot"]["name"] == "rx60"
    manifest["robot"] = {"model": "staubli_rx60", "urdf_sha256": manifest["robot"]["model_sha256"]}
    del manifest["config"]["robot"]
    manifest_path.write_text(yaml.safe_dump(manifest, sort_keys=False))
    saved = open_scan(scan_dir)
    assert saved.config.robot == "rx60"
    captures = [saved.store.read_capture(i) for i in saved.store.captured_indices()]
    assert captures and all(c.q_rad.shape == (6,) for c in captures)


@pytest.fixture(scope="module")
def ur5e_scan(tmp_path_factory):
    from scanner.scan.run import run_scan

    folder = tmp_path_factory.mktemp("ur5e")
    return run_scan(load_scan_config(write_config(folder, UR5E_SCAN)), folder / "scan")


def test_a_simulated_scan_with_the_ur5e_captures_its_views_and_reconstructs(ur5e_scan):
    saved = open_scan(ur5e_scan.scan_dir)
    arm = arm_of(saved.config.robot)
    robot = saved.manifest["robot"]
    assert robot["name"] == "ur5e" and Path(robot["arm_file"]) == UR5E_FILE
    assert robot["joint_names"] == list(arm.joint_names)
    indices = saved.store.captured_indices()
    # The object hangs where the UR5e reaches it from every direction the tiny scan picks.
    assert len(indices) == len(saved.views) == TINY_SCAN["views"]["count"]
    for i in indices:
        capture = saved.store.read_capture(i)
        assert capture.q_rad.shape == (arm.joint_count,)
        assert arm.within_limits(capture.q_rad)
        X_WF = arm.X_WF(capture.q_rad).GetAsMatrix4()
        assert np.abs(X_WF[:3, 3] - capture.X_WF[:3, 3]).max() < FLANGE_TOL_M
    report = ur5e_scan.report
    assert report["status"] == "complete" and report["views_captured"] == len(indices)
    assert report["chamfer_observed_mm"] < CHAMFER_OBSERVED_MAX_MM


def test_calibrate_refuses_a_bad_robot_flag_in_one_line(tmp_path, capfd):
    r = scanner(capfd, "calibrate", "--robot", "kuka", "--out", tmp_path / "c")
    assert r.returncode == 2
    assert "--robot: expected 'rx60' or the path of an arm file, got 'kuka'" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_the_robot_error_model_is_the_configured_arms():
    from reconstruction.calibration.settings import CalibrationSettings
    from scanner.calibrate.config import CalibrateConfig

    config = CalibrateConfig(robot=str(UR5E_FILE), solver=CalibrationSettings(robot_offsets=True))
    assert arm_of(config.robot).error_model().arm_name == "ur5e"


def test_the_calibration_cell_is_built_for_the_configured_arm():
    from scanner.calibrate.config import CalibrateConfig
    from scanner.calibrate.eye_in_hand import build_world

    world = build_world(CalibrateConfig(robot=str(UR5E_FILE)))
    assert world.planner.arm.name == world.sim.robot.arm.name == "ur5e"
    assert world.kinematics.arm.name == "ur5e"
    assert world.is_free(world.robot.joint_positions())


def test_a_calibration_with_another_arms_own_errors_is_refused_for_a_scan(ur5e_scan, tmp_path):
    """Joint offsets and link lengths estimated for the RX60 would move another arm's flange
    poses by another chain's kinematics: refused in one line before anything is written (the
    same arm's are accepted: test_arm_errors.py)."""
    from reconstruction.calibration.file import Calibration, RobotCorrection, save_calibration
    from scanner.configs.scan import ScanConfig
    from scanner.reconstruct.command import ReconstructOptions, reconstruct_one

    stereo = ScanConfig().camera.stereo_camera()
    robot = RobotCorrection((0.0, 1e-4, 0.0, 0.0, 0.0, 0.0), {})
    path = save_calibration(
        Calibration(np.eye(4), stereo, stereo.left, robot=robot), tmp_path / "c.yaml"
    )
    out = tmp_path / "out"
    with pytest.raises(ScannerError, match="joint offsets and link lengths are arm rx60's"):
        reconstruct_one(ur5e_scan.scan_dir, ReconstructOptions(calibration=path, out=out))
    assert not out.exists()


# An arm nobody ships, written as two files into the test's folder, hangs a 0.1 m object in
# front of its shoulder (upper arm 0.4 m, forearm 0.35 m) and looks at it from 0.3 m: 4 of the
# 16 directions below are reachable there.
TINY6_SCAN = {
    **TINY_SCAN,
    "cell": {"object_center_m": [0.4, 0.0, 0.4], "object_size_m": 0.1},
    # Each candidate direction and roll is a numerical IK request (about 0.1 s).
    "views": {
        **TINY_SCAN["views"],
        "count": 3,
        "radius_m": 0.3,
        "candidates": 16,
        "roll_candidates": 2,
    },
}


def test_an_arm_added_as_two_files_plans_and_simulates_a_scan(tmp_path):
    from scanner.scan.run import run_scan

    arm_file = write_tiny_arm(tmp_path, base_pose="{xyz_m: [0, 0, 0], rpy_rad: [0, 0, 0]}")
    config = load_scan_config(write_config(tmp_path, {**TINY6_SCAN, "robot": str(arm_file)}))
    result = run_scan(config, tmp_path / "scan")
    saved = open_scan(result.scan_dir)
    arm = arm_of(saved.config.robot)
    assert saved.manifest["robot"]["name"] == "tiny6"
    assert Path(saved.manifest["robot"]["arm_file"]) == arm_file
    indices = saved.store.captured_indices()
    assert len(indices) == TINY6_SCAN["views"]["count"]
    for i in indices:
        capture = saved.store.read_capture(i)
        assert capture.q_rad.shape == (6,) and arm.within_limits(capture.q_rad)
        X_WF = arm.X_WF(capture.q_rad).GetAsMatrix4()
        assert np.abs(X_WF[:3, 3] - capture.X_WF[:3, 3]).max() < FLANGE_TOL_M
    report = result.report
    assert report["status"] == "complete" and report["views_captured"] == len(indices)
    assert report["chamfer_observed_mm"] < CHAMFER_OBSERVED_MAX_MM

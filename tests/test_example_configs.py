"""The example configurations shipped in scanner/configs/ load, validate and say what their
comments promise; the default one is exactly the built-in defaults."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from scanner.configs.scan import ScanConfig, load_scan_config, scan_config_to_dict

CONFIGS = Path(__file__).resolve().parents[1] / "scanner" / "configs"


def write_nominal_calibration(path: Path) -> Path:
    """A calibration file of the nominal camera and mount (what an uncalibrated scan assumes)."""
    from reconstruction.calibration.file import Calibration, save_calibration
    from robots.models.camera_tool import nominal_X_FC

    stereo = ScanConfig().camera.stereo_camera()
    path.parent.mkdir(parents=True, exist_ok=True)
    calibration = Calibration(nominal_X_FC(stereo.baseline_m), stereo, stereo.left, "test")
    return save_calibration(calibration, path)


def test_every_example_is_tested():
    assert {p.name for p in CONFIGS.glob("*.yaml")} == {
        "default.yaml",
        "two-hangings.yaml",
        "hardware.yaml",
        "emulated-cell.yaml",
        "monitor.yaml",
    }


def test_the_default_example_is_the_built_in_default():
    assert scan_config_to_dict(load_scan_config(CONFIGS / "default.yaml")) == scan_config_to_dict(
        ScanConfig()
    )


@pytest.mark.parametrize(
    "name, expected",
    [
        ("two-hangings.yaml", {"hangings": 2, "views.count": 24, "views.max_extra_views": 4}),
        (
            "hardware.yaml",
            {
                "driver": None,
                "hardware.robot.kind": "staubli_val3",
                "hardware.robot.host": "192.168.0.254",
                "hardware.robot.motion_port": 11000,
                "hardware.robot.state_port": 11002,
                "hardware.camera.kind": "opencv",
                "hardware.camera.left": 0,
                "hardware.camera.right": 1,
                # Read from the configuration's folder (a copy of the example, with a
                # calibration file where the example names one).
                "calibration_file": "{folder}/calibration/calibration.yaml",
                "views.radius_m": 0.5,
                "hangings": 1,
            },
        ),
        (
            "emulated-cell.yaml",
            {
                "hardware.robot.host": "127.0.0.1",
                "hardware.robot.motion_port": 11000,
                "hardware.camera.kind": "simulated",
                "hangings": 1,
            },
        ),
        ("monitor.yaml", {"monitor.enabled": True, "monitor.intruder_start_s": (4.0, 20.0)}),
    ],
)
def test_each_example_sets_what_it_says_and_keeps_the_rest(name, expected, tmp_path):
    shutil.copy(CONFIGS / name, tmp_path / name)
    write_nominal_calibration(tmp_path / "calibration" / "calibration.yaml")
    config = load_scan_config(tmp_path / name)
    for path, value in expected.items():
        got = config
        for part in path.split("."):
            got = getattr(got, part)
        if isinstance(value, str):
            value = value.format(folder=tmp_path)
        assert got == value, path
    # Everything the example does not name keeps its default.
    default = ScanConfig()
    assert config.processing == default.processing
    assert config.planner == default.planner

"""Sensor kinds as plug-ins: the registry names the known kinds when a configuration names
another; a driver's camera must be of the configured sensor's driver type; and a kind that a
test registers (a perfect depth camera) scans the simulated cell end to end, its simulated
device and its clouds asked through the registry, and models the true object."""

from __future__ import annotations

import json

import pytest
import yaml

from reconstruction.common.errors import ScannerError
from robots.drivers.interfaces import DepthCameraDriver, load_hardware
from robots.sensors import register_sensor, sensor_kinds, sensor_named
from robots.sensors.registry import unregister_sensor
from scanner.configs.scan import ScanConfig
from tests.in_process import scanner
from tests.sensor_plugins import PerfectDepthSensor
from tests.tiny_scan import TINY_SCAN


def test_the_built_in_kinds_are_registered():
    assert sensor_kinds()[:3] == ("stereo", "rgbd", "mono")
    # mono (imported recordings) is a kind of capture, not one a scan runs with.
    assert "mono" not in sensor_kinds(scanning=True)
    assert sensor_named("mono").pairs_of_captures and not sensor_named("stereo").pairs_of_captures


def test_an_unknown_sensor_is_one_line_naming_the_field_and_the_kinds():
    with pytest.raises(ScannerError) as e:
        ScanConfig(sensor="lidar")
    message = str(e.value)
    assert message.startswith("sensor: expected one of stereo, rgbd")
    assert message.endswith("got 'lidar'") and "\n" not in message
    with pytest.raises(ScannerError, match="sensor: expected one of stereo, rgbd.*got 'mono'"):
        ScanConfig(sensor="mono")


def test_a_driver_camera_of_another_kind_is_refused_in_one_line():
    spec = "tests.sensor_plugins:stereo_cell"
    with pytest.raises(ScannerError) as e:
        load_hardware(spec, ScanConfig(sensor="rgbd"), sensor_named("rgbd"))
    assert str(e.value) == (
        f"driver: {spec} returned a Hardware whose camera is a BlankStereo; sensor rgbd "
        "expects a DepthCameraDriver"
    )
    spec = "tests.sensor_plugins:depth_cell"
    with pytest.raises(ScannerError, match="sensor stereo expects a StereoCameraDriver"):
        load_hardware(spec, ScanConfig(), sensor_named("stereo"))
    # A depth camera from --driver, for the depth sensor.
    hardware = load_hardware(spec, ScanConfig(sensor="rgbd"), sensor_named("rgbd"))
    assert isinstance(hardware.camera, DepthCameraDriver)


@pytest.fixture
def perfect_depth():
    sensor = register_sensor(PerfectDepthSensor())
    yield sensor
    unregister_sensor(sensor.kind)


@pytest.mark.slow
def test_a_registered_kind_scans_and_models_the_true_object(perfect_depth, tmp_path, capfd):
    assert "perfect_depth" in sensor_kinds(scanning=True)
    config = {
        **TINY_SCAN,
        "sensor": "perfect_depth",
        # The device at a quarter of its pixels, depth in 0.1 mm counts (the tiny scan's
        # coarse surfaces resolve no finer), and no hand-eye or joint error: only the sensor
        # is judged.
        "rgbd": {
            "depth_width_px": 424,
            "depth_height_px": 240,
            "color_width_px": 480,
            "color_height_px": 270,
            "depth_scale_m": 0.0001,
        },
        "error_model": {
            "handeye_translation_m": 0.0,
            "handeye_rotation_rad": 0.0,
            "joint_offset_std_rad": 0.0,
        },
    }
    path = tmp_path / "perfect.yaml"
    path.write_text(yaml.safe_dump(config))
    r = scanner(capfd, "scan", "--config", path, "--out", tmp_path / "scan")
    assert r.returncode == 0, r.stderr
    manifest = yaml.safe_load((tmp_path / "scan" / "scan.yaml").read_text())
    assert manifest["config"]["sensor"] == "perfect_depth"
    # The scan rendered with the kind's own device and made its clouds through it.
    assert perfect_depth.devices >= 1 and perfect_depth.clouds >= 5
    report = json.loads((tmp_path / "scan" / "results" / "report.json").read_text())
    fused = report["surfaces"]["fused_cloud"]
    # The true depth in 0.1 mm counts puts every point within 0.05 mm of the true surface;
    # the fused cloud's 2 mm voxels average points of a nearly flat patch (measured: p90
    # 0.024 mm, mean 0.012 mm; the noisy RGB-D device's are tenths of a millimetre).
    assert fused["accuracy_p90_mm"] < 0.1, fused
    assert fused["observed_fraction"] > 0.5, fused


def test_an_installed_package_registers_a_kind_by_entry_point(monkeypatch):
    import robots.sensors.registry as registry

    class Point:
        name = "perfect_depth"

        def load(self):
            return PerfectDepthSensor

    monkeypatch.setattr(registry, "entry_points", lambda group: [Point()])
    try:
        assert registry.load_entry_points() == ["perfect_depth"]
        assert isinstance(sensor_named("perfect_depth"), PerfectDepthSensor)
    finally:
        unregister_sensor("perfect_depth")
    assert "perfect_depth" not in sensor_kinds()

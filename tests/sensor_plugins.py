"""A sensor kind that is not built in, for the tests: `perfect_depth`, a depth camera that
reports the true depth (no noise, no dropouts), registered by the tests through
`register_sensor`; and small driver factories for `load_hardware`."""

from __future__ import annotations

import time

import numpy as np

from robots.drivers.interfaces import (
    DepthCameraDriver,
    Hardware,
    RgbdImages,
    RobotDriver,
    StereoCameraDriver,
    StereoImages,
)
from robots.sensors.rgbd import RgbdSensor
from robots.simulation.depth_camera import SimulatedDepthCamera


class PerfectDepthCamera(SimulatedDepthCamera):
    """The true device's renders at the arm's true pose: depth as rendered, in counts of the
    depth unit (0 outside the device's range), colour without sensor noise."""

    def capture(self) -> RgbdImages:
        rgbd = self._truth.rgbd
        X_WC = self.true_X_WC()
        z_m = self._render_depth(X_WC @ rgbd.X_CD)
        seen = np.isfinite(z_m) & (z_m >= rgbd.min_depth_m) & (z_m <= rgbd.max_depth_m)
        counts = np.where(seen, np.round(z_m / rgbd.depth_scale_m), 0).astype(np.uint16)
        color = self._render_rgb(self._color, X_WC)
        return RgbdImages(counts, rgbd.depth_scale_m, color, stamp_s=time.time())


class PerfectDepthSensor(RgbdSensor):
    """The RGB-D kind's model, files and clouds (depth lifted straight into the colour frame),
    with the perfect device in the simulated cell; counts what it was asked."""

    kind = "perfect_depth"
    hardware_kinds = ()

    def __init__(self) -> None:
        self.devices = 0
        self.clouds = 0

    def simulated_device(self, workcell, truth, true_joint_positions):
        self.devices += 1
        return PerfectDepthCamera(
            workcell, truth, true_joint_positions, truth.rgbd.depth_baseline_m
        )

    def cloud(self, prepared, capture, X_WC, p_W_centre, radius_m, params, step_px=None):
        self.clouds += 1
        return super().cloud(prepared, capture, X_WC, p_W_centre, radius_m, params, step_px)


class StillRobot(RobotDriver):
    def joint_positions(self) -> np.ndarray:
        return np.zeros(6)

    def execute(self, trajectory) -> None:
        pass


class BlankStereo(StereoCameraDriver):
    def capture(self) -> StereoImages:
        image = np.zeros((4, 4, 3), np.uint8)
        return StereoImages(image, image, 0.0)


class BlankDepth(DepthCameraDriver):
    def capture(self) -> RgbdImages:
        return RgbdImages(np.zeros((4, 4), np.uint16), 0.001, np.zeros((4, 4, 3), np.uint8), 0.0)


def stereo_cell(config) -> Hardware:
    """`--driver tests.sensor_plugins:stereo_cell`: an arm with a stereo camera."""
    return Hardware(StillRobot(), BlankStereo())


def depth_cell(config) -> Hardware:
    """`--driver tests.sensor_plugins:depth_cell`: an arm with a depth camera."""
    return Hardware(StillRobot(), BlankDepth())

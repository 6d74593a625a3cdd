"""The depth (RGB-D) camera: depth images with a colour camera beside them
(`reconstruction/depth/`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from reconstruction.calibration.file import calibrated_rgbd
from reconstruction.common.errors import ScannerError
from reconstruction.depth.camera_model import (
    SCHEMA,
    RgbdCamera,
    rgbd_camera_from_dict,
    rgbd_camera_to_dict,
)
from reconstruction.depth.cloud import view_rgbd_cloud
from reconstruction.stereo.params import object_depth_window
from robots.drivers.interfaces import DepthCameraDriver
from robots.models import camera_tool
from robots.sensors.sensor import Sensor, SensorCloud


class RgbdSensor(Sensor):
    kind = "rgbd"
    capture_format = "rgbd"
    model_words = "an RGB-D device"
    device_words = "an RGB-D camera"
    driver_type = DepthCameraDriver
    hardware_kinds = ("realsense",)
    model_schema = SCHEMA
    solves_depth_scale = True

    def nominal_model(self, config) -> RgbdCamera:
        return config.rgbd.rgbd_camera()

    def nominal_X_FC(self, model: RgbdCamera) -> np.ndarray:
        return camera_tool.rig_X_FC(model.X_CR)

    def calibrated_model(self, model: RgbdCamera, calibration, where: str) -> RgbdCamera:
        return calibrated_rgbd(model, calibration, where)

    def model_to_dict(self, model: RgbdCamera) -> dict:
        return rgbd_camera_to_dict(model)

    def model_from_dict(self, d: dict, where: str) -> RgbdCamera:
        return rgbd_camera_from_dict(d, where)

    def board_intrinsics(self, model: RgbdCamera):
        """The colour camera's factory intrinsics: one camera's intrinsics from a few board
        views are worse (measured in simulation with 10 stations: X_FC 2.35 mm and the depth
        scale 0.58 % off with calibrated intrinsics, 0.26 mm and 0.012 % with the device's
        own)."""
        return model.color

    def describe(self, model: RgbdCamera) -> str:
        (dw, dh), (cw, ch) = model.depth_size, model.image_size
        return f"RGB-D camera (depth {dw}x{dh}, colour {cw}x{ch})"

    def image_camera(self, model: RgbdCamera):
        return model.color

    def check_reach(self, model: RgbdCamera, standoff_m: float, radius_m: float) -> None:
        z_min, z_max = object_depth_window(standoff_m, radius_m)
        if z_min < model.min_depth_m or z_max > model.max_depth_m:
            raise ScannerError(
                f"views.radius_m: at {standoff_m} m the object spans depths "
                f"{z_min:.3f}-{z_max:.3f} m; the depth camera measures "
                f"{model.min_depth_m}-{model.max_depth_m} m (rgbd.min_depth_m, max_depth_m)"
            )

    def cloud(self, prepared, capture, X_WC, p_W_centre, radius_m, params, step_px=None):
        if step_px is not None:
            c = view_rgbd_cloud(
                prepared, capture.depth, capture.left, X_WC, p_W_centre, radius_m, step_px
            )
            return SensorCloud(c.points_C, c.colors, None)
        if capture.depth_scale_m != prepared.depth_scale_m:
            raise ScannerError(
                f"depth unit {capture.depth_scale_m} m differs from the device model's "
                f"{prepared.depth_scale_m} m"
            )
        c = view_rgbd_cloud(prepared, capture.depth, capture.left, X_WC, p_W_centre, radius_m)
        return SensorCloud(c.points_C, c.colors, c.depth)

    def true_device(self, config) -> RgbdCamera:
        return config.rgbd.rgbd_camera()

    def simulated_device(self, workcell, truth, true_joint_positions):
        from robots.simulation.depth_camera import SimulatedDepthCamera

        return SimulatedDepthCamera(
            workcell, truth, true_joint_positions, truth.rgbd.depth_baseline_m
        )

    def driver_model(self, camera, model: RgbdCamera, calibrated: RgbdCamera | None):
        """A real depth camera's model is what the device reports (`camera.rgbd_camera()`: its
        intrinsics, depth unit, depth aligned to colour); a calibration adds its depth
        correction and its colour intrinsics (the aligned depth lies on the colour grid)."""
        reported = getattr(camera, "rgbd_camera", None)
        if reported is None:
            return model
        device = reported()
        if calibrated is None:
            return device
        if calibrated.image_size != device.image_size:
            raise ScannerError(
                f"calibration_file: calibrated for {calibrated.image_size[0]}x"
                f"{calibrated.image_size[1]} colour images, the camera delivers "
                f"{device.image_size[0]}x{device.image_size[1]}"
            )
        device = replace(device, depth_correction=calibrated.depth_correction)
        return replace(device, color=calibrated.color, depth=calibrated.color)

    def open_driver(self, settings, model: RgbdCamera):
        from robots.drivers.connect import open_depth_camera

        return open_depth_camera(settings)

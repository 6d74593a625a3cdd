"""The stereo pair: SGBM on a calibrated, rectified pair (`reconstruction/stereo/`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from reconstruction.calibration.file import calibrated_stereo
from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import (
    SCHEMA,
    StereoCamera,
    stereo_camera_from_dict,
    stereo_camera_to_dict,
)
from reconstruction.stereo.cloud import depth_image, view_cloud
from reconstruction.stereo.params import disparity_window, object_depth_window
from reconstruction.stereo.rectification import Rectification, compute_rectification
from robots.drivers.interfaces import StereoCameraDriver
from robots.models import camera_tool
from robots.sensors.sensor import Sensor, SensorCloud


class StereoSensor(Sensor):
    kind = "stereo"
    capture_format = "stereo"
    model_words = "a stereo pair"
    device_words = "a stereo camera"
    driver_type = StereoCameraDriver
    hardware_kinds = ("opencv",)
    model_schema = SCHEMA

    def nominal_model(self, config) -> StereoCamera:
        return config.camera.stereo_camera()

    def nominal_X_FC(self, model: StereoCamera) -> np.ndarray:
        return camera_tool.nominal_X_FC(model.baseline_m)

    def calibrated_model(self, model: StereoCamera, calibration, where: str) -> StereoCamera:
        return calibrated_stereo(model, calibration, where)

    def offline_model(self, model: StereoCamera, calibration, where: str):
        """The calibration's pair; None (a one-camera calibration): the scan's own pair."""
        return calibration.stereo

    def model_to_dict(self, model: StereoCamera) -> dict:
        return stereo_camera_to_dict(model)

    def model_from_dict(self, d: dict, where: str) -> StereoCamera:
        return stereo_camera_from_dict(d, where)

    def describe(self, model: StereoCamera) -> str:
        w, h = model.image_size
        return f"stereo pair ({w}x{h}, baseline {1000 * model.baseline_m:.0f} mm)"

    def image_camera(self, model: StereoCamera):
        return model.left

    def check_reach(self, model: StereoCamera, standoff_m: float, radius_m: float) -> None:
        """Left-image columns below min_disparity + num_disparities have no match in the right
        image; the remaining band must hold at least half the object's image (its bounding
        sphere's image radius f r / d), else most of the object is never measured."""
        rect = compute_rectification(model)
        z_min, z_max = object_depth_window(standoff_m, radius_m)
        min_d, num_d = disparity_window(z_min, z_max, rect.focal_px, rect.baseline_m)
        width = rect.image_size[0]
        usable_px = width - (min_d + num_d)
        needed_px = rect.focal_px * radius_m / standoff_m
        if usable_px < needed_px:
            raise ScannerError(
                f"views.radius_m: at {standoff_m} m the object spans depths "
                f"{z_min:.3f}-{z_max:.3f} m (disparities {min_d}-{min_d + num_d} px): only "
                f"{max(usable_px, 0)} px of the {width} px wide image can be matched, less than "
                f"half the object's image ({needed_px:.0f} px); use a larger radius"
            )

    def prepare(self, model: StereoCamera) -> Rectification:
        return compute_rectification(model)

    def cloud(self, prepared, capture, X_WC, p_W_centre, radius_m, params, step_px=None):
        if step_px is not None:
            params = replace(params, subsample_step_px=step_px)
            c = view_cloud(
                prepared, capture.left, capture.right, X_WC, p_W_centre, radius_m, params
            )
            return SensorCloud(c.points_C, c.colors, None)
        if capture.left.shape[1::-1] != prepared.image_size:
            raise ScannerError(
                f"image size {capture.left.shape[1::-1]} differs from the camera model's"
            )
        c = view_cloud(prepared, capture.left, capture.right, X_WC, p_W_centre, radius_m, params)
        return SensorCloud(c.points_C, c.colors, depth_image(prepared, c))

    def true_device(self, config) -> None:
        return None

    def simulated_device(self, workcell, truth, true_joint_positions):
        from robots.simulation.stereo_camera import SimulatedStereoCamera

        return SimulatedStereoCamera(workcell, truth, true_joint_positions)

    def open_driver(self, settings, model: StereoCamera):
        """The pair, opened and checked to deliver the calibration's image size."""
        from robots.drivers.connect import open_camera

        return open_camera(settings, model.image_size)

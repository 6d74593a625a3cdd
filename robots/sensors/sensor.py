"""The interface one kind of sensor implements (see the package's docstring)."""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.registration.views import DepthImage
from reconstruction.stereo.camera_model import PinholeCamera


@dataclass(frozen=True, eq=False)
class SensorCloud:
    """One capture as a cloud: points_C (N, 3) metres in the camera frame C, colors (N, 3)
    uint8, and the depth map for fusion (None when the cloud was subsampled for a preview)."""

    points_C: np.ndarray
    colors: np.ndarray
    depth: DepthImage | None


class Sensor(abc.ABC):
    """What a scan, its reconstruction and its calibration ask of the sensor on the tool.

    A camera model (`model`) is the kind's own record (a StereoCamera, an RgbdCamera, ...);
    `config` is a ScanConfig or a CalibrateConfig (both carry the `camera:` and `rgbd:`
    sections). Methods a kind cannot do raise ScannerError saying so in one line.
    """

    kind: ClassVar[str]  # the name in `sensor:` and in a scan's manifest
    # The files of one capture (scanner/scan_dir/capture_formats.py): "stereo" (left.png,
    # right.png), "rgbd" (color.png, depth.png) or "mono" (image.png and its own camera);
    # kinds may share one.
    capture_format: ClassVar[str]
    model_words: ClassVar[str]  # what the camera model is, for messages: "a stereo pair"
    device_words: ClassVar[str]  # what the device is, for messages: "a stereo camera"
    # The `hardware: camera: kind:` values that open a device of this kind.
    hardware_kinds: ClassVar[tuple[str, ...]] = ()
    # The driver interface (robots.drivers.interfaces) a `--driver` or `hardware:` camera of
    # this kind implements; None: the kind has no live device.
    driver_type: ClassVar[type | None] = None
    # True: a cloud needs two captures (a recording's single camera moved by the arm), so
    # `cloud` is never asked; the reconstruction pairs views first.
    pairs_of_captures: ClassVar[bool] = False
    # False: the kind's captures are only imported (a recording), never scanned.
    scans: ClassVar[bool] = True
    # The `schema` of its camera-model file section (None: the kind has no such file); kinds
    # may share one (the first registered reads a file that names no kind).
    model_schema: ClassVar[str | None] = None
    # What a calibration solves besides X_FC: True, the device's depth scale too.
    solves_depth_scale: ClassVar[bool] = False

    # -- the camera model -----------------------------------------------------------------
    @abc.abstractmethod
    def nominal_model(self, config):
        """The camera model of the configuration's design (before any calibration)."""

    @abc.abstractmethod
    def nominal_X_FC(self, model) -> np.ndarray:
        """Where the tool holds the camera C (the flange frame F), by design."""

    @abc.abstractmethod
    def calibrated_model(self, model, calibration, where: str):
        """The model a calibration file makes of the nominal `model` (`where` names it)."""

    def offline_model(self, model, calibration, where: str):
        """The model `scanner reconstruct --calibration` uses for a scan taken with `model`;
        None: the scan's own."""
        return self.calibrated_model(model, calibration, where)

    @abc.abstractmethod
    def model_to_dict(self, model) -> dict:
        """The camera model as a file section (scan.yaml's `camera:`)."""

    def model_from_dict(self, d: dict, where: str):
        """The camera model of a file section written by `model_to_dict` (`where` names it)."""
        raise ScannerError(f"{where}: sensor {self.kind} has no camera-model file")

    @abc.abstractmethod
    def describe(self, model) -> str:
        """What measured depth, for reports: 'stereo pair (1280x960, baseline 120 mm)'."""

    @abc.abstractmethod
    def image_camera(self, model) -> PinholeCamera:
        """The camera whose images are kept and shown (and that sees a calibration board)."""

    def board_intrinsics(self, model) -> PinholeCamera | None:
        """The intrinsics a calibration keeps for the camera the board is seen by (a device's
        factory ones); None: the calibration solves them."""
        return None

    # -- reach -----------------------------------------------------------------------------
    @abc.abstractmethod
    def check_reach(self, model, standoff_m: float, radius_m: float) -> None:
        """Refuse, before moving, a standoff (views.radius_m) at which this sensor cannot
        measure an object within a sphere of `radius_m` (one-line ScannerError naming
        views.radius_m)."""

    # -- clouds ----------------------------------------------------------------------------
    def prepare(self, model):
        """What turning captures into clouds needs of the model, computed once per scan."""
        return model

    @abc.abstractmethod
    def cloud(
        self,
        prepared,
        capture,
        X_WC: np.ndarray,
        p_W_centre: np.ndarray,
        radius_m: float,
        params,
        step_px: int | None = None,
    ) -> SensorCloud:
        """One capture's cloud in C, only the depths the object (a sphere of `radius_m` about
        `p_W_centre`) can occupy; `params`: the stereo matcher's settings; `step_px`: every
        step-th pixel, for a preview (no depth map then). A capture that does not fit the
        model raises ScannerError saying why."""

    # -- devices ---------------------------------------------------------------------------
    @abc.abstractmethod
    def true_device(self, config):
        """The device model the simulator renders with, beside the stereo design it always
        holds (an RgbdCamera for a depth camera, None when the stereo pair is the device)."""

    @abc.abstractmethod
    def simulated_device(self, workcell, truth, true_joint_positions):
        """The simulated camera driver on the tool of the Drake cell `workcell`, rendering at
        the arm's true joints (`true_joint_positions()`)."""

    def open_driver(self, settings, model):
        """The `hardware: camera:` section's device of this kind, opened."""
        raise ScannerError(
            f"hardware.camera.kind: '{settings.kind}' is not a camera for sensor {self.kind}"
        )

    def driver_model(self, camera, model, calibrated):
        """The camera model a scan on the driver `camera` uses: `model` (the nominal or
        `calibrated` one, None without a calibration file), unless the device reports its
        own."""
        return model

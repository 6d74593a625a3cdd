"""The small interfaces a robot and a camera implement: the simulator and real drivers.

A real-hardware port implements `RobotDriver` (e.g. over the Staubli controller's socket
interface) and the camera interface of the configured sensor kind (robots.sensors):
`StereoCameraDriver` (e.g. a FlyCapture/Spinnaker grabber) or `DepthCameraDriver` (an RGB-D
camera); nothing else in the product needs to change.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class JointTrajectory:
    """A time-parameterised joint path sampled densely enough to be executed by interpolation.

    times_s: (K,) strictly increasing from 0; positions_rad: (K, 6).
    joint_linear: the straight joint-space path through the positions was itself checked
    (collision, limits) at the dense-validation resolution, so a controller that moves
    point to point in straight joint-space lines may run it (planners.joint_linear).
    """

    times_s: np.ndarray
    positions_rad: np.ndarray
    joint_linear: bool = False

    def __post_init__(self) -> None:
        t, q = np.asarray(self.times_s, float), np.asarray(self.positions_rad, float)
        if t.ndim != 1 or q.ndim != 2 or len(t) != len(q) or len(t) < 2:
            raise ValueError("JointTrajectory: times (K,) and positions (K, n) with K >= 2")
        if np.any(np.diff(t) <= 0) or t[0] != 0:
            raise ValueError("JointTrajectory: times must start at 0 and strictly increase")
        t.setflags(write=False)
        q.setflags(write=False)
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "positions_rad", q)

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1])


@dataclass(frozen=True, eq=False)
class StereoImages:
    """One synchronised stereo pair: RGB uint8 images (H, W, 3) and the capture time stamp."""

    left: np.ndarray
    right: np.ndarray
    stamp_s: float


@dataclass(frozen=True, eq=False)
class RgbdImages:
    """One RGB-D capture: depth (H, W) uint16 counts of depth_scale_m metres each (0: no
    depth), on the depth camera's grid; colour RGB uint8 (h, w, 3) on the colour camera's;
    the capture time stamp."""

    depth: np.ndarray
    depth_scale_m: float
    color: np.ndarray
    stamp_s: float


class RobotDriver(abc.ABC):
    """A 6-axis arm: report measured joints, execute a (validated) trajectory until at rest."""

    # What execute() runs: "sampled", the trajectory's curve (interpolating its samples), or
    # "joint_linear", straight joint-space moves from position to position (a controller fed
    # waypoints); the scan then gives it waypoints checked as such a path.
    motion: str = "sampled"

    @abc.abstractmethod
    def joint_positions(self) -> np.ndarray:
        """Measured joint positions (rad), shape (6,)."""

    @abc.abstractmethod
    def execute(self, trajectory: JointTrajectory) -> None:
        """Follow the trajectory and return once the arm has settled at its last sample."""


class StereoCameraDriver(abc.ABC):
    """A stereo camera on the flange: capture one synchronised pair."""

    @abc.abstractmethod
    def capture(self) -> StereoImages:
        """Grab a pair; raise CaptureError when the hardware could not deliver one."""


class DepthCameraDriver(abc.ABC):
    """A depth (RGB-D) camera on the flange: capture one depth image with its colour image."""

    @abc.abstractmethod
    def capture(self) -> RgbdImages:
        """Grab a depth + colour pair; raise CaptureError when the device could not deliver."""


class TurntableDriver(abc.ABC):
    """A motorised turntable under the object: turn to an absolute angle, report the angle."""

    @abc.abstractmethod
    def rotate_to(self, angle_rad: float) -> None:
        """Turn to `angle_rad` (about the vertical, right hand) and return once at rest."""

    @abc.abstractmethod
    def angle_rad(self) -> float:
        """The angle the turntable's encoder reports now (rad)."""


class CaptureError(RuntimeError):
    """The camera failed to deliver an image pair (the decision maker retries)."""


@dataclass(frozen=True, eq=False)
class Hardware:
    """A real (or any other) robot and camera that a scan runs on instead of the simulator; a
    driver module's factory returns one. The camera is of the configured sensor's driver type
    (robots.sensors: a StereoCameraDriver for `stereo`, a DepthCameraDriver for `rgbd`)."""

    robot: RobotDriver
    camera: StereoCameraDriver | DepthCameraDriver
    # Multi-hanging scans: ask the operator to re-hang the object (the message says which
    # hanging and how) and return once it hangs still; None: this cell cannot re-hang.
    request_rehang: Callable[[str], None] | None = None
    # Turntable scans (presentation: turntable): the turntable the object stands on; None:
    # this cell has none.
    turntable: TurntableDriver | None = None


def load_hardware(spec: str, config: object, sensor=None) -> Hardware:
    """`package.module:factory` -> factory(config) -> Hardware, e.g. `my_cell.rx60:connect`.

    The factory gets the command's whole configuration (a ScanConfig or a CalibrateConfig:
    cell, camera, sensor, ...) and connects to the hardware. Its camera must be of the driver
    type of `sensor`, the configured sensor kind (a robots.sensors.Sensor: `kind`,
    `driver_type`; None: the stereo pair's). Every failure to find or call it is a user error
    naming `spec`.
    """
    from reconstruction.common.errors import ScannerError
    from robots.drivers.driver_module import driver_factory

    kind = "stereo" if sensor is None else sensor.kind
    driver_type = StereoCameraDriver if sensor is None else sensor.driver_type
    try:
        factory = driver_factory(spec)
    except ScannerError as e:
        raise ScannerError(f"driver: {e}") from None
    hardware = factory(config)
    wanted = getattr(driver_type, "__name__", "camera driver")
    if not (
        isinstance(hardware, Hardware)
        and isinstance(hardware.robot, RobotDriver)
        and (hardware.turntable is None or isinstance(hardware.turntable, TurntableDriver))
    ):
        raise ScannerError(
            f"driver: {spec} returned {type(hardware).__name__}; "
            "expected robots.drivers.interfaces.Hardware"
            f" holding a RobotDriver and a {wanted}"
        )
    if driver_type is None or not isinstance(hardware.camera, driver_type):
        raise ScannerError(
            f"driver: {spec} returned a Hardware whose camera is a "
            f"{type(hardware.camera).__name__}; sensor {kind} expects a {wanted}"
        )
    return hardware

"""The `hardware:` section of a configuration: which robot link and which camera a scan runs on.

Kinds are chosen by name; a kind's own fields sit beside `kind` (unused ones keep their
defaults). Anything not covered here plugs in through `--driver MODULE:FACTORY`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from reconstruction.common.checks import (
    check_fields,
    integer,
    positive,
    require_choice,
)
from reconstruction.common.errors import ScannerError

ROBOT_KINDS = ("staubli_val3",)
# The slowest movej the driver commands, as a fraction of each joint's nominal speed. The VAL 3
# server turns the fraction into a percentage and rounds it to 1e-4 % before movej
# (interpolateVel.pgx), and it rewrites exactly 0.1 % into another speed; a fraction of 1e-38
# is accepted and holds the queue for ever. At 1 % a radian already takes 20 s on the RX60's
# slowest joints (287 deg/s nominal, robots/arms/rx60.py): nothing slower is ever needed.
MIN_SPEED_FRACTION = 0.01
# The VAL 3 server streams STATUS every 5th 20 ms cycle (dataStreamer.pgx, start.pgx): a state
# timeout shorter than two such periods would stop the arm on one late STATUS.
MIN_STATE_TIMEOUT_S = 0.2
# "simulated": the scan's own simulated cell rendered at the joints the robot link reports
# (with the controller emulator: a whole scan over the wire without a camera).
CAMERA_KINDS = ("opencv", "realsense", "simulated")


@dataclass(frozen=True)
class RobotLinkConfig:
    """The arm's controller. staubli_val3: the ROS-Industrial VAL 3 server on a CS8/CS9
    controller (its default ports); speed_fraction: movej speed as a fraction of each joint's
    nominal speed, at least MIN_SPEED_FRACTION; path_tolerance_rad: how far a measured joint may
    leave the commanded joint-linear path before the arm is stopped; state_timeout_s: the age
    limit of the joints and of STATUS (either older stops the arm; at least
    MIN_STATE_TIMEOUT_S), and of the wait for each point's reply; connect_timeout_s: for each
    TCP connection and the first state."""

    kind: str = "staubli_val3"
    host: str = "127.0.0.1"
    motion_port: int = integer(11000, maximum=65535)
    state_port: int = integer(11002, maximum=65535)
    speed_fraction: float = positive(0.25, at_most=1.0)
    path_tolerance_rad: float = positive(0.02)
    state_timeout_s: float = positive(0.5)
    connect_timeout_s: float = positive(3.0)

    def __post_init__(self) -> None:
        require_choice("hardware.robot", "kind", self.kind, ROBOT_KINDS)
        if not self.host:
            raise ScannerError("hardware.robot.host: expected a host name or address, got ''")
        check_fields("hardware.robot", self)
        require_speed_fraction(self.speed_fraction)
        if not self.state_timeout_s >= MIN_STATE_TIMEOUT_S:
            raise ScannerError(
                f"hardware.robot.state_timeout_s: expected at least {MIN_STATE_TIMEOUT_S} s "
                f"(two periods of the controller's STATUS), got {self.state_timeout_s!r}"
            )


def require_speed_fraction(speed_fraction: float) -> None:
    """The driver commands no movej slower than MIN_SPEED_FRACTION (written so NaN fails)."""
    if not MIN_SPEED_FRACTION <= speed_fraction <= 1.0:
        raise ScannerError(
            f"hardware.robot.speed_fraction: expected a fraction of nominal speed in "
            f"[{MIN_SPEED_FRACTION}, 1], got {speed_fraction!r}"
        )


@dataclass(frozen=True)
class CameraLinkConfig:
    """The stereo camera. opencv: two OpenCV video sources (`left`, `right`: a device index,
    a device path, a URL or an image-sequence pattern such as `rec/left_%04d.png`), or one
    source delivering side-by-side frames (`side_by_side: true`, `right` unset); both are
    grabbed before either is retrieved, and grabs further apart than max_skew_s are refused.
    realsense: an Intel RealSense depth camera (sensor: rgbd) through its SDK, depth and colour
    at width_px x height_px and fps, depth aligned to colour by the SDK; `serial` picks one of
    several. simulated: the scan's simulated cell, rendered at the joints the robot link
    reports."""

    kind: str = "opencv"
    left: int | str = 0
    right: int | str | None = 1
    side_by_side: bool = False
    max_skew_s: float = positive(0.01)
    # Grabs that fail in a row before the capture is reported failed (the scan then retries).
    grab_attempts: int = integer(3)
    serial: str | None = None
    width_px: int = integer(848, minimum=16)
    height_px: int = integer(480, minimum=16)
    fps: int = integer(30)

    def __post_init__(self) -> None:
        require_choice("hardware.camera", "kind", self.kind, CAMERA_KINDS)
        if self.kind == "opencv":
            if self.side_by_side and self.right is not None:
                raise ScannerError(
                    "hardware.camera.right: expected no right source with side_by_side: true "
                    f"(one device delivers both images), got {self.right!r}"
                )
            if not self.side_by_side and self.right is None:
                raise ScannerError(
                    "hardware.camera.right: expected the right camera's source (or "
                    "side_by_side: true), got none"
                )
        for side in ("left", "right"):
            source = getattr(self, side)
            if isinstance(source, int) and source < 0 or isinstance(source, str) and not source:
                raise ScannerError(
                    f"hardware.camera.{side}: expected a device index >= 0, a device path, a "
                    f"URL or a recording, got {source!r}"
                )
        if self.serial is not None and not self.serial.strip():
            raise ScannerError("hardware.camera.serial: expected a serial number, or none, got ''")
        check_fields("hardware.camera", self)


@dataclass(frozen=True)
class HardwareConfig:
    robot: RobotLinkConfig = field(default_factory=RobotLinkConfig)
    camera: CameraLinkConfig = field(default_factory=CameraLinkConfig)

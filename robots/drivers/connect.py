"""The `hardware:` section's kinds made into drivers (the simulated camera kind is the caller's:
it renders the caller's own simulated cell)."""

from __future__ import annotations

from robots.drivers.interfaces import DepthCameraDriver, RobotDriver, StereoCameraDriver
from robots.drivers.settings import CameraLinkConfig, RobotLinkConfig


def connect_robot(settings: RobotLinkConfig) -> RobotDriver:
    """The arm's controller, connected and streaming its state (one-line ScannerError else)."""
    from robots.drivers.staubli_val3 import Val3Robot

    return {"staubli_val3": Val3Robot}[settings.kind](settings)


def open_camera(settings: CameraLinkConfig, image_size: tuple[int, int]) -> StereoCameraDriver:
    """The stereo camera, opened and checked to deliver `image_size` (width, height) images,
    the calibration's, before anything moves."""
    from robots.drivers.opencv_stereo import open_stereo_camera

    camera = open_stereo_camera(settings, image_size)
    try:
        camera.check_size()
    except BaseException:
        camera.close()
        raise
    return camera


def open_depth_camera(settings: CameraLinkConfig) -> DepthCameraDriver:
    """The RGB-D camera, started (one-line ScannerError when absent, busy or unable)."""
    from robots.drivers.realsense import RealSenseCamera

    return RealSenseCamera(settings.serial, settings.width_px, settings.height_px, settings.fps)


def close_all(*parts: object) -> None:
    """Close what has a close() (drivers holding sockets or devices)."""
    for part in parts:
        close = getattr(part, "close", None)
        if close is not None:
            close()

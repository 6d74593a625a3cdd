"""An Intel RealSense RGB-D camera through pyrealsense2: depth aligned to colour, one pipeline.

Depth is aligned to the colour grid by the SDK (`rs.align`), so the device model has one
camera: the depth camera equals the colour camera and X_CD = I. Hand-eye calibration finds the
colour camera, which is therefore the frame every depth pixel lands in.

SDK behaviour this relies on (2.59): `pipeline.start` raises RuntimeError for a configuration
the device cannot deliver and for a device another program holds; `wait_for_frames` raises
RuntimeError when nothing arrived in time; the pipeline only returns framesets that hold every
enabled stream; `context.query_devices()` lists the devices a pipeline on that context can use.
"""

from __future__ import annotations

import contextlib
import time
from types import TracebackType
from typing import Any

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.depth.camera_model import RgbdCamera
from reconstruction.stereo.camera_model import PinholeCamera
from robots.drivers.interfaces import CaptureError, DepthCameraDriver, RgbdImages

try:
    import pyrealsense2 as rs
except ImportError:  # Only a cell with a RealSense needs the SDK; say so when one is asked for.
    rs = None

_ITEM = "hardware.camera"


def _serials(context: Any) -> list[str]:
    return [
        device.get_info(rs.camera_info.serial_number)
        for device in context.query_devices()
        if device.supports(rs.camera_info.serial_number)
    ]


def _opencv_distortion(intrinsics: Any) -> np.ndarray:
    """The SDK's distortion as OpenCV's (k1, k2, p1, p2, k3); refuse a model OpenCV lacks."""
    model = intrinsics.model
    coeffs = np.array(intrinsics.coeffs[:5], float)
    if model == rs.distortion.none:
        return np.zeros(5)
    # The SDK orders Brown-Conrady coefficients as OpenCV does (rs2_project_point_to_pixel).
    # "Modified" evaluates the tangential terms at the radially distorted point: it differs from
    # OpenCV's model only by products of tangential and radial coefficients, both small here.
    if model in (rs.distortion.brown_conrady, rs.distortion.modified_brown_conrady):
        return coeffs
    # Zero coefficients are the identity in every Brown-Conrady variant (colour streams of some
    # D400 firmware report inverse Brown-Conrady with all zeros): nothing to refuse then.
    if model == rs.distortion.inverse_brown_conrady and not coeffs.any():
        return np.zeros(5)
    raise ScannerError(
        f"{_ITEM}: the RealSense reports its colour distortion as {getattr(model, 'name', model)} "
        f"with coefficients {coeffs.tolist()}, which is not OpenCV's model; "
        "expected Brown-Conrady or none"
    )


class RealSenseCamera(DepthCameraDriver):
    """A RealSense streaming depth (z16) and colour (rgb8) at one size and rate.

    serial: the device to use, or None for the first one found; min/max_depth_m: the range the
    device model states (the device does not report it); timeout_s: how long a capture waits
    for a frameset; context: the `rs.context` to find devices in (None: a new one).
    """

    def __init__(
        self,
        serial: str | None = None,
        width_px: int = 848,
        height_px: int = 480,
        fps: int = 30,
        min_depth_m: float = 0.1,
        max_depth_m: float = 3.0,
        context: Any = None,
        timeout_s: float = 1.0,
    ) -> None:
        if rs is None:
            raise ScannerError(
                f"{_ITEM}: the RealSense driver needs pyrealsense2 (pip install pyrealsense2)"
            )
        if not 0 < min_depth_m < max_depth_m:
            raise ScannerError(
                f"{_ITEM}: expected 0 < min_depth_m < max_depth_m, got {min_depth_m}, {max_depth_m}"
            )
        if not timeout_s > 0:
            raise ScannerError(f"{_ITEM}: expected a positive capture timeout, got {timeout_s} s")
        self._min_depth_m = float(min_depth_m)
        self._max_depth_m = float(max_depth_m)
        self._timeout_ms = max(1, round(timeout_s * 1000))
        self._pipeline: Any = None
        # Look before starting: the pipeline's own errors ("No device connected", "Couldn't
        # resolve requests") do not say which of the two is wrong.
        try:
            self._context = rs.context() if context is None else context
            serials = _serials(self._context)
        except RuntimeError as e:  # The USB backend (or a device answering it) failed.
            raise ScannerError(f"{_ITEM}: cannot list the RealSense devices ({e})") from None
        if not serials:
            raise ScannerError(
                f"{_ITEM}: no RealSense device found: is it connected and not in use by another "
                "program?"
            )
        if serial is not None and serial not in serials:
            raise ScannerError(
                f"{_ITEM}.serial: no RealSense with serial '{serial}' "
                f"(connected: {', '.join(serials)})"
            )

        config = rs.config()
        if serial is not None:
            config.enable_device(serial)
        config.enable_stream(rs.stream.depth, width_px, height_px, rs.format.z16, fps)
        config.enable_stream(rs.stream.color, width_px, height_px, rs.format.rgb8, fps)
        try:
            pipeline = rs.pipeline(self._context)
            self._profile = pipeline.start(config)
        except RuntimeError as e:
            raise ScannerError(
                f"{_ITEM}: the RealSense could not start {width_px}x{height_px} depth and colour "
                f"at {fps} Hz ({e})"
            ) from None
        self._pipeline = pipeline
        try:
            depth_sensor = self._profile.get_device().first_depth_sensor()
            # The projector's pattern gives texture to plain surfaces; a recorded (playback)
            # device exposes the option read-only, so only a writable option is set.
            emitter = rs.option.emitter_enabled
            if depth_sensor.supports(emitter) and not depth_sensor.is_option_read_only(emitter):
                depth_sensor.set_option(emitter, 1)
            self._depth_scale_m = float(depth_sensor.get_depth_scale())
            self._color_intrinsics = (
                self._profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
            )
        except RuntimeError as e:
            self.close()
            raise ScannerError(f"{_ITEM}: the RealSense could not be set up ({e})") from None
        if not (np.isfinite(self._depth_scale_m) and self._depth_scale_m > 0):
            self.close()
            raise ScannerError(
                f"{_ITEM}: the RealSense reports a depth unit of {self._depth_scale_m} m; "
                "expected a positive number"
            )
        # The depth-to-colour extrinsics come from the device; after this the depth image lies
        # on the colour grid.
        self._align = rs.align(rs.stream.color)

    def capture(self) -> RgbdImages:
        if self._pipeline is None:
            raise RuntimeError("RealSenseCamera: capture() after close()")
        try:
            frames = self._pipeline.wait_for_frames(self._timeout_ms)
        except RuntimeError as e:
            raise CaptureError(
                f"{_ITEM}: no depth and colour frames within {self._timeout_ms} ms ({e})"
            ) from None
        return self._images_of(frames)

    def _images_of(self, frames: Any) -> RgbdImages:
        """A frameset (depth + colour) as RgbdImages: depth aligned to colour, copied out."""
        try:
            aligned = self._align.process(frames)
            depth_frame = aligned.get_depth_frame()
            color_frame = aligned.get_color_frame()
        except RuntimeError as e:
            raise CaptureError(f"{_ITEM}: aligning depth to colour failed ({e})") from None
        if not depth_frame or not color_frame:
            missing = "depth" if not depth_frame else "colour"
            raise CaptureError(f"{_ITEM}: the frameset has no {missing} frame")
        # Copies: the arrays would otherwise view SDK buffers that it reuses once released.
        depth = np.array(depth_frame.get_data(), dtype=np.uint16, copy=True)
        color = np.array(color_frame.get_data(), dtype=np.uint8, copy=True)
        if depth.ndim != 2 or color.ndim != 3 or color.shape[2] != 3:
            raise CaptureError(
                f"{_ITEM}: unexpected image shapes: depth {depth.shape}, colour {color.shape}"
            )
        # Host-clock domains are milliseconds since the epoch, comparable with the rest of the
        # product's time.time() stamps; the device's own clock (hardware_clock) is not, so such
        # frames get the host time of their arrival (later than the exposure by the transfer).
        domain = color_frame.get_frame_timestamp_domain()
        if domain in (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time):
            stamp_s = color_frame.get_timestamp() / 1000.0
        else:
            stamp_s = time.time()
        return RgbdImages(depth, self._depth_scale_m, color, stamp_s)

    def rgbd_camera(self) -> RgbdCamera:
        """The device as it reports itself: colour intrinsics for both cameras (aligned)."""
        i = self._color_intrinsics
        K = np.array([[i.fx, 0.0, i.ppx], [0.0, i.fy, i.ppy], [0.0, 0.0, 1.0]])
        camera = PinholeCamera(K, _opencv_distortion(i), int(i.width), int(i.height))
        return RgbdCamera(
            camera, camera, np.eye(4), self._depth_scale_m, self._min_depth_m, self._max_depth_m
        )

    def close(self) -> None:
        pipeline, self._pipeline = self._pipeline, None
        if pipeline is not None:
            # An unplugged device leaves nothing to stop.
            with contextlib.suppress(RuntimeError):
                pipeline.stop()

    def __enter__(self) -> RealSenseCamera:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

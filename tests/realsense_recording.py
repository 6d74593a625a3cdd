"""A RealSense for the tests, without a camera: frames fed to the SDK's `software_device` and
recorded, then played back through the real pipeline.

pyrealsense2 2.59 does not let a pipeline use a live `rs.software_device`: `sd.add_to(ctx)`
registers it with a device-info that nothing keeps alive, so `ctx.query_devices()` stays empty.
A recording of that software device does work: `rs.recorder` writes the frames (only to .db3,
ROS 2 bags) and `ctx.load_device(file)` puts the playback into a context, where a driver finds
it by serial. Playback runs in real time and does not loop.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rs = pytest.importorskip("pyrealsense2")

FPS = 30
# A context that sees neither USB cameras nor network (DDS) ones: only what a test loads.
SOFTWARE_ONLY = '{"device-mask": 256, "dds": false}'


def intrinsics(K: np.ndarray, width: int, height: int, model: Any = None, coeffs=(0.0,) * 5):
    i = rs.intrinsics()
    i.width, i.height = width, height
    i.fx, i.fy, i.ppx, i.ppy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    i.model = rs.distortion.none if model is None else model
    i.coeffs = list(coeffs)
    return i


def video_stream(kind: Any, uid: int, fmt: Any, bpp: int, intr: Any) -> Any:
    s = rs.video_stream()
    s.type, s.index, s.uid, s.width, s.height, s.fps = kind, 0, uid, intr.width, intr.height, FPS
    s.bpp, s.fmt, s.intrinsics = bpp, fmt, intr
    return s


def record(
    path: Path,
    frames: list[tuple[np.ndarray, np.ndarray]],
    K: np.ndarray,
    depth_unit_m: float,
    serial: str,
    color_model: Any = None,
    color_coeffs: tuple[float, ...] = (0.0,) * 5,
    domain: Any = None,
    t0_ms: float = 0.0,
) -> Path:
    """A software device (depth z16 + colour rgb8, both with K, the colour camera's distortion
    as given, identity extrinsics, `depth_unit_m`) streaming `frames` ((depth counts, RGB)
    pairs) at matching time stamps, recorded to path.db3."""
    height, width = frames[0][0].shape
    domain = rs.timestamp_domain.hardware_clock if domain is None else domain
    device = rs.software_device()
    device.create_matcher(rs.matchers.default)
    device.register_info(rs.camera_info.serial_number, serial)
    device.register_info(rs.camera_info.name, "Software RealSense")
    depth_sensor = device.add_sensor("Depth")
    color_sensor = device.add_sensor("Color")
    depth_profile = depth_sensor.add_video_stream(
        video_stream(rs.stream.depth, 0, rs.format.z16, 2, intrinsics(K, width, height))
    ).as_video_stream_profile()
    color_intrinsics = intrinsics(K, width, height, color_model, color_coeffs)
    color_profile = color_sensor.add_video_stream(
        video_stream(rs.stream.color, 1, rs.format.rgb8, 3, color_intrinsics)
    ).as_video_stream_profile()
    depth_sensor.add_read_only_option(rs.option.depth_units, depth_unit_m)
    # A real D400 has a writable emitter; its recording (like this one) plays it read-only.
    depth_sensor.add_option(rs.option.emitter_enabled, rs.option_range(0, 1, 1, 0), True)
    identity = rs.extrinsics()
    identity.rotation, identity.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [0, 0, 0]
    depth_profile.register_extrinsics_to(color_profile, identity)

    path = path.with_suffix(".db3")  # 2.59 records ROS 2 bags and refuses other names
    recorder = rs.recorder(str(path), device)
    received: list[int] = []
    for sensor, profile in ((depth_sensor, depth_profile), (color_sensor, color_profile)):
        sensor.open(profile)
        sensor.start(lambda frame: received.append(frame.get_frame_number()))
    for n, (depth, color) in enumerate(frames):
        for sensor, profile, pixels, bpp in (
            (depth_sensor, depth_profile, np.ascontiguousarray(depth, np.uint16), 2),
            (color_sensor, color_profile, np.ascontiguousarray(color, np.uint8), 3),
        ):
            frame = rs.software_video_frame()
            frame.pixels, frame.stride, frame.bpp = pixels, width * bpp, bpp
            frame.timestamp, frame.domain, frame.frame_number = t0_ms + n * 1000 / FPS, domain, n
            frame.profile = profile
            sensor.on_video_frame(frame)
        # Playback replays frames at the times they were recorded: paced like a camera, so
        # the frames that arrive while the pipeline is still starting its sensors are few.
        time.sleep(1 / FPS)
    for sensor in (depth_sensor, color_sensor):
        sensor.stop()
        sensor.close()
    recorder.pause()
    del recorder  # closes the file
    assert len(received) == 2 * len(frames)
    return path


@dataclass
class Loaded:
    """A context holding a recorded device. The context only keeps a weak reference to the
    device, so the playback object must live as long as the context is used."""

    context: Any
    playback: Any


def load(path: Path) -> Loaded:
    context = rs.context(SOFTWARE_ONLY)
    return Loaded(context, context.load_device(str(path)))


def release(loaded: Loaded) -> None:
    """The playback paused and taken out of its context, then dropped before the context, in
    this order, rather than by the garbage collector in either order while the playback's
    reader could still run (which aborted the process now and then under load)."""
    with contextlib.suppress(RuntimeError):
        loaded.playback.pause()
    with contextlib.suppress(RuntimeError):
        loaded.context.unload_device(loaded.playback.file_name())
    loaded.playback = None
    loaded.context = None

"""The RealSense driver on a software device, through the SDK's real pipeline (no camera here).

pyrealsense2 2.59 does not let a pipeline use a live `rs.software_device`: `sd.add_to(ctx)`
registers it with a device-info that nothing keeps alive, so `ctx.query_devices()` stays empty
and `pipeline.start` says "No device connected". A recording of that software device does work:
its frames (fed with `on_video_frame`) are written with `rs.recorder` (.db3), and
`ctx.load_device(file)` puts the playback device into the context, where the driver finds it by
serial and streams it through `rs.pipeline`, `rs.align` and `wait_for_frames` as it would a
camera. Playback runs in real time and does not loop: once its frames are out, captures time out.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from robots.drivers.interfaces import CaptureError
from robots.drivers.realsense import RealSenseCamera
from tests import realsense_recording as recording
from tests.realsense_recording import SOFTWARE_ONLY, Loaded, load, release

rs = pytest.importorskip("pyrealsense2")

W, H, FPS = 64, 48, recording.FPS
F_PX, CX, CY = 60.0, 32.0, 24.0
SERIAL = "SW-0001"
FRAMES = 12
DEPTH_UNIT_M = 0.001
BROWN = (0.1, -0.05, 0.001, -0.002, 0.01)


def plane_counts() -> np.ndarray:
    """Depth counts (H, W) of a plane 0.5 m ahead on the optical axis, tilted about the y axis
    (z = 0.5 + 0.3 x), with a hole (0: no depth) in one corner."""
    x_over_z = (np.arange(W) - CX) / F_PX
    z_m = 0.5 / (1 - 0.3 * x_over_z)
    counts = np.round(np.tile(z_m, (H, 1)) / DEPTH_UNIT_M).astype(np.uint16)
    counts[5:15, 5:15] = 0
    return counts


def rgb_pattern() -> np.ndarray:
    """Red on the left, blue on the right (red != blue, so a BGR swap shows), green rows."""
    image = np.zeros((H, W, 3), np.uint8)
    image[:, : W // 2] = (220, 0, 10)
    image[:, W // 2 :] = (10, 0, 220)
    image[::4, :, 1] = 128
    return image


K_DEVICE = np.array([[F_PX, 0.0, CX], [0.0, F_PX, CY], [0.0, 0.0, 1.0]])


def record(
    path: Path,
    color_model: Any = None,
    color_coeffs: tuple[float, ...] = (0.0,) * 5,
    domain: Any = None,
    t0_ms: float = 0.0,
) -> Path:
    """The software device (identical intrinsics, identity extrinsics, 1 mm depth unit)
    streaming FRAMES pairs of the tilted plane and the colour pattern, recorded."""
    frames = [(plane_counts(), rgb_pattern())] * FRAMES
    return recording.record(
        path, frames, K_DEVICE, DEPTH_UNIT_M, SERIAL, color_model, color_coeffs, domain, t0_ms
    )


@pytest.fixture
def loads():
    """`load`, with every recording it loaded released when the test ends (see `release`)."""
    loaded: list[Loaded] = []

    def load_recording(path: Path) -> Loaded:
        loaded.append(load(path))
        return loaded[-1]

    yield load_recording
    for each in loaded:
        release(each)


@pytest.fixture
def plain(tmp_path: Path, loads) -> Loaded:
    return loads(record(tmp_path / "plain"))


class _RecordedCamera(RealSenseCamera):
    """The driver on a recorded device, whose playback is paused before the driver closes: a
    playback still reading its file while the SDK tore the pipeline down aborted the process
    now and then (about one run of this file in two with both cores busy)."""

    def __init__(self, loaded: Loaded, **kwargs: Any) -> None:
        self._playback = loaded.playback
        super().__init__(context=loaded.context, width_px=W, height_px=H, fps=FPS, **kwargs)

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):
            self._playback.pause()
        super().close()


def open_camera(loaded: Loaded, **kwargs: Any) -> RealSenseCamera:
    return _RecordedCamera(loaded, **kwargs)


def test_depth_comes_back_on_the_colour_grid_and_colour_in_rgb(plain: Loaded) -> None:
    before = time.time()
    with open_camera(plain, serial=SERIAL) as camera:
        images = camera.capture()
    after = time.time()
    assert images.depth.shape == (H, W) and images.depth.dtype == np.uint16
    assert images.color.shape == (H, W, 3) and images.color.dtype == np.uint8
    assert images.depth_scale_m == pytest.approx(DEPTH_UNIT_M, rel=1e-6)
    # Identical intrinsics, identity extrinsics: alignment keeps each depth where it was. The
    # SDK fills the colour pixels between a depth pixel's corners, each rounded to the grid, and
    # drops pixels whose corners leave the image: the last row and column come out empty, and a
    # hole's edge may take its neighbour's depth.
    expected = plane_counts()
    out = images.depth.astype(int)
    both = (out > 0) & (expected > 0)
    assert both.sum() >= 0.9 * (expected > 0).sum()
    assert np.abs(out - expected)[both].max() <= 1
    assert not out[6:14, 6:14].any()  # the hole's inside stays without depth
    for r, c in np.argwhere((out > 0) & (expected == 0)):
        around = expected[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2].astype(int)
        assert np.abs(around[around > 0] - out[r, c]).min() <= 1, (r, c)
    centre_m = out[:, int(CX)][both[:, int(CX)]] * images.depth_scale_m
    assert len(centre_m) > H // 2 and np.allclose(centre_m, 0.5, atol=DEPTH_UNIT_M)
    assert (images.color == rgb_pattern()).all()
    assert tuple(images.color[1, 0]) == (220, 0, 10)  # red, not blue: RGB order
    # hardware_clock stamps are the device's own time: the driver stamps with the host's.
    assert before <= images.stamp_s <= after


def test_host_clock_frame_stamps_are_kept(tmp_path: Path, loads) -> None:
    t0_ms = 1.7e12
    loaded = loads(record(tmp_path / "global", domain=rs.timestamp_domain.global_time, t0_ms=t0_ms))
    with open_camera(loaded) as camera:
        stamp_s = camera.capture().stamp_s
    recorded_s = (t0_ms + np.arange(FRAMES) * 1000 / FPS) / 1000
    assert np.isclose(recorded_s, stamp_s, rtol=0, atol=1e-6).any(), stamp_s


@pytest.mark.parametrize(
    ("model", "coeffs", "expected"),
    [
        ("none", (0.0,) * 5, (0.0,) * 5),
        ("brown_conrady", BROWN, BROWN),
        ("modified_brown_conrady", BROWN, BROWN),
        ("inverse_brown_conrady", (0.0,) * 5, (0.0,) * 5),
    ],
)
def test_the_model_is_the_device_as_it_reports_itself(
    tmp_path: Path, loads, model: str, coeffs: tuple[float, ...], expected: tuple[float, ...]
) -> None:
    loaded = loads(record(tmp_path / model, getattr(rs.distortion, model), coeffs))
    with open_camera(loaded, min_depth_m=0.2, max_depth_m=2.0) as camera:
        rgbd = camera.rgbd_camera()
    K = np.array([[F_PX, 0, CX], [0, F_PX, CY], [0, 0, 1]])
    assert np.allclose(rgbd.color.K, K) and rgbd.image_size == (W, H)
    assert np.allclose(rgbd.color.distortion, expected, atol=1e-7)
    assert rgbd.depth is rgbd.color and np.array_equal(rgbd.X_CD, np.eye(4))
    assert rgbd.depth_scale_m == pytest.approx(DEPTH_UNIT_M, rel=1e-6)
    assert (rgbd.min_depth_m, rgbd.max_depth_m) == (0.2, 2.0)


def test_inverse_brown_conrady_is_refused(tmp_path: Path, loads) -> None:
    loaded = loads(record(tmp_path / "inverse", rs.distortion.inverse_brown_conrady, BROWN))
    with open_camera(loaded) as camera, pytest.raises(ScannerError) as error:
        camera.rgbd_camera()
    message = str(error.value)
    assert message.startswith("hardware.camera: ") and "inverse_brown_conrady" in message
    assert "not OpenCV's model" in message and "\n" not in message


def test_a_capture_with_no_frames_coming_fails_within_the_timeout(plain: Loaded) -> None:
    with open_camera(plain, timeout_s=0.3) as camera:
        delivered = 0
        # The recording plays its frames once, in real time; then nothing comes any more.
        for _ in range(FRAMES + 2):
            start = time.monotonic()
            try:
                camera.capture()
            except CaptureError as e:
                waited_s, message = time.monotonic() - start, str(e)
                break
            delivered += 1
        else:
            pytest.fail("captures kept succeeding after the recording ended")
    assert 1 <= delivered <= FRAMES
    assert 0.25 <= waited_s <= 1.5
    assert "no depth and colour frames within 300 ms" in message


def test_close_releases_the_device_and_is_idempotent(plain: Loaded) -> None:
    camera = open_camera(plain)
    camera.close()
    camera.close()
    with pytest.raises(RuntimeError, match="after close"):
        camera.capture()
    # The device is free again: a second driver starts on it.
    with open_camera(plain) as again:
        assert again.rgbd_camera().image_size == (W, H)


def test_no_device_is_one_line() -> None:
    with pytest.raises(ScannerError) as error:
        RealSenseCamera(context=rs.context(SOFTWARE_ONLY))
    assert str(error.value) == (
        "hardware.camera: no RealSense device found: is it connected and not in use by another "
        "program?"
    )


def test_a_serial_that_is_not_connected_names_the_item(plain: Loaded) -> None:
    with pytest.raises(ScannerError) as error:
        open_camera(plain, serial="123456")
    assert str(error.value) == (
        f"hardware.camera.serial: no RealSense with serial '123456' (connected: {SERIAL})"
    )


def test_a_size_the_device_does_not_offer_cannot_start(plain: Loaded) -> None:
    with pytest.raises(ScannerError) as error:
        RealSenseCamera(context=plain.context, width_px=640, height_px=480, fps=FPS)
    message = str(error.value)
    assert message.startswith(
        "hardware.camera: the RealSense could not start 640x480 depth and colour at 30 Hz ("
    )
    assert "\n" not in message
    # Nothing was left running: the offered size still starts.
    with open_camera(plain) as camera:
        assert camera.capture().depth.shape == (H, W)


def test_a_bad_depth_range_is_refused_before_any_device_is_touched() -> None:
    with pytest.raises(ScannerError, match="0 < min_depth_m < max_depth_m"):
        RealSenseCamera(min_depth_m=2.0, max_depth_m=1.0, context=rs.context(SOFTWARE_ONLY))

"""The OpenCV stereo camera driver, on recorded image sequences (no camera hardware here) and on
fake capture objects put in through the driver's `_open` seam."""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from robots.drivers import opencv_stereo
from robots.drivers.interfaces import CaptureError
from robots.drivers.opencv_stereo import OpenCvStereoCamera, open_stereo_camera
from robots.drivers.settings import CameraLinkConfig

FRAMES = 5
WIDTH, HEIGHT = 64, 48


def rgb_of(side: str, frame: int) -> tuple[int, int, int]:
    """A distinct colour per side and frame, with red != blue so a BGR/RGB swap shows."""
    return (200, 10 * frame, 0) if side == "left" else (0, 10 * frame, 200)


def record(folder: Path, side: str, width: int = WIDTH, height: int = HEIGHT) -> str:
    """Write FRAMES images `side_0000.png ...` of constant colour; returns the sequence pattern."""
    for i in range(FRAMES):
        image = np.zeros((height, width, 3), np.uint8)
        image[:] = rgb_of(side, i)
        assert cv2.imwrite(str(folder / f"{side}_{i:04d}.png"), image[:, :, ::-1])  # RGB->BGR
    return str(folder / f"{side}_%04d.png")


def camera_settings(folder: Path, **fields: Any) -> CameraLinkConfig:
    return CameraLinkConfig(left=record(folder, "left"), right=record(folder, "right"), **fields)


def test_captures_return_the_recorded_pairs_in_order_as_rgb(tmp_path: Path) -> None:
    with open_stereo_camera(camera_settings(tmp_path), (WIDTH, HEIGHT)) as camera:
        pairs = [camera.capture() for _ in range(FRAMES)]
    for i, pair in enumerate(pairs):
        for side, image in (("left", pair.left), ("right", pair.right)):
            assert image.shape == (HEIGHT, WIDTH, 3) and image.dtype == np.uint8
            assert (image == rgb_of(side, i)).all(), (side, i, image[0, 0])
    stamps = [pair.stamp_s for pair in pairs]
    assert all(b > a for a, b in zip(stamps, stamps[1:], strict=False))


def test_side_by_side_frames_split_into_left_and_right(tmp_path: Path) -> None:
    for i in range(FRAMES):
        frame = np.zeros((HEIGHT, 2 * WIDTH, 3), np.uint8)
        frame[:, :WIDTH] = rgb_of("left", i)
        frame[:, WIDTH:] = rgb_of("right", i)
        cv2.imwrite(str(tmp_path / f"sbs_{i:04d}.png"), frame[:, :, ::-1])
    settings = CameraLinkConfig(left=str(tmp_path / "sbs_%04d.png"), right=None, side_by_side=True)
    with OpenCvStereoCamera(settings, (WIDTH, HEIGHT)) as camera:
        assert camera.check_size() == (WIDTH, HEIGHT)  # consumes frame 0
        pair = camera.capture()
    assert pair.left.shape == pair.right.shape == (HEIGHT, WIDTH, 3)
    assert (pair.left == rgb_of("left", 1)).all() and (pair.right == rgb_of("right", 1)).all()


def test_side_by_side_frames_of_odd_width_or_wrong_size_are_user_errors(tmp_path: Path) -> None:
    odd = CameraLinkConfig(left=record(tmp_path, "odd", width=65), right=None, side_by_side=True)
    with OpenCvStereoCamera(odd) as camera, pytest.raises(ScannerError) as error:
        camera.capture()
    assert "hardware.camera.left" in str(error.value) and "65 pixels wide" in str(error.value)
    sbs = CameraLinkConfig(left=record(tmp_path, "sbs", width=128), right=None, side_by_side=True)
    with OpenCvStereoCamera(sbs, (128, 48)) as camera, pytest.raises(ScannerError) as error:
        camera.check_size()
    assert "64x48" in str(error.value) and "128x48" in str(error.value)


def test_a_size_other_than_the_calibrations_is_a_user_error(tmp_path: Path) -> None:
    settings = camera_settings(tmp_path)
    for check in (OpenCvStereoCamera.check_size, OpenCvStereoCamera.capture):
        with OpenCvStereoCamera(settings, (80, 60)) as camera, pytest.raises(ScannerError) as error:
            check(camera)
        message = str(error.value)
        assert message.startswith("hardware.camera.left: delivers 64x48 images")
        assert "80x60" in message and "\n" not in message


def test_left_and_right_of_different_sizes_are_a_user_error(tmp_path: Path) -> None:
    settings = CameraLinkConfig(
        left=record(tmp_path, "left"), right=record(tmp_path, "right", width=32, height=24)
    )
    with OpenCvStereoCamera(settings) as camera, pytest.raises(ScannerError) as error:
        camera.capture()
    assert "hardware.camera.right" in str(error.value) and "32x24" in str(error.value)


def test_sources_that_do_not_open_are_user_errors_naming_the_item(tmp_path: Path) -> None:
    missing_pattern = str(tmp_path / "nothing_%04d.png")
    with pytest.raises(ScannerError) as error:
        OpenCvStereoCamera(CameraLinkConfig(left=missing_pattern, right=record(tmp_path, "right")))
    assert str(error.value).startswith(f"hardware.camera.left: cannot open '{missing_pattern}'")
    assert "image-sequence pattern" in str(error.value)
    missing_file = str(tmp_path / "no_such_video.avi")
    with pytest.raises(ScannerError) as error:
        OpenCvStereoCamera(CameraLinkConfig(left=record(tmp_path, "left"), right=missing_file))
    assert str(error.value).startswith(f"hardware.camera.right: cannot open '{missing_file}'")


def test_the_end_of_a_recording_is_a_capture_error(tmp_path: Path) -> None:
    with OpenCvStereoCamera(camera_settings(tmp_path, grab_attempts=2)) as camera:
        for _ in range(FRAMES):
            camera.capture()
        with pytest.raises(CaptureError) as error:
            camera.capture()
    assert "grab failed" in str(error.value) and "2 attempts" in str(error.value)


class Clock:
    """Stands in for the driver's `time` module: only grabs move it."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def monotonic(self) -> float:
        return self.now_s

    def time(self) -> float:
        return 1.7e9 + self.now_s


class LateRight:
    """Wraps a real capture so that the given grabs (0-based) complete `late_s` after the left."""

    def __init__(self, capture: Any, clock: Clock, late_grabs: set[int], late_s: float) -> None:
        self.capture, self.clock, self.late_grabs, self.late_s = capture, clock, late_grabs, late_s
        self.grabs = 0

    def grab(self) -> bool:
        self.clock.now_s += self.late_s if self.grabs in self.late_grabs else 0.001
        self.grabs += 1
        return self.capture.grab()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.capture, name)


def late_right_camera(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, late_grabs: set[int]
) -> tuple[OpenCvStereoCamera, LateRight]:
    clock = Clock()
    fake_time = types.SimpleNamespace(monotonic=clock.monotonic, time=clock.time)
    monkeypatch.setattr(opencv_stereo, "time", fake_time)
    wrapped: list[LateRight] = []

    def open_(source: Any, *args: Any) -> Any:
        capture = cv2.VideoCapture(source, *args)
        if "right" in str(source):
            wrapped.append(LateRight(capture, clock, late_grabs, late_s=0.034))
            return wrapped[-1]
        return capture

    monkeypatch.setattr(opencv_stereo, "_open", open_)
    camera = OpenCvStereoCamera(camera_settings(tmp_path, max_skew_s=0.01, grab_attempts=3))
    return camera, wrapped[0]


def test_grabs_too_far_apart_are_refused_after_the_retries(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    camera, right = late_right_camera(tmp_path, monkeypatch, late_grabs={0, 1, 2})
    with camera, pytest.raises(CaptureError) as error:
        camera.capture()
    assert "left and right grabbed 0.034 s apart (hardware.camera.max_skew_s: 0.01)" in str(
        error.value
    )
    assert right.grabs == 3


def test_a_single_late_grab_is_retried(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    camera, right = late_right_camera(tmp_path, monkeypatch, late_grabs={0})
    with camera:
        pair = camera.capture()
    # The refused pair 0 was grabbed and dropped; the retry delivers pair 1 on both sides.
    assert (pair.left == rgb_of("left", 1)).all() and (pair.right == rgb_of("right", 1)).all()
    assert right.grabs == 2


class FakeCapture:
    """A capture object that logs its calls; `pos_ms`: what it reports as CAP_PROP_POS_MSEC."""

    def __init__(self, name: str, log: list[str], pos_ms: float = 0.0, opens: bool = True) -> None:
        self.name, self.log, self.pos_ms, self.opens = name, log, pos_ms, opens
        self.failed_retrieves = 0

    def isOpened(self) -> bool:  # noqa: N802 (OpenCV's name)
        return self.opens

    def grab(self) -> bool:
        self.log.append(f"grab {self.name}")
        return True

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        self.log.append(f"retrieve {self.name}")
        if self.failed_retrieves > 0:
            self.failed_retrieves -= 1
            return False, None
        return True, np.zeros((4, 6, 3), np.uint8)

    def get(self, prop: int) -> float:
        return self.pos_ms if prop == cv2.CAP_PROP_POS_MSEC else 0.0

    def release(self) -> None:
        self.log.append(f"release {self.name}")


def fake_camera(
    monkeypatch: pytest.MonkeyPatch, fakes: dict[str, FakeCapture], **fields: Any
) -> OpenCvStereoCamera:
    monkeypatch.setattr(opencv_stereo, "_open", lambda source, *args: fakes[source])
    return OpenCvStereoCamera(CameraLinkConfig(left="L", right="R", **fields))


def test_both_grabs_happen_before_either_retrieve(monkeypatch: pytest.MonkeyPatch) -> None:
    log: list[str] = []
    fakes = {"L": FakeCapture("left", log), "R": FakeCapture("right", log)}
    with fake_camera(monkeypatch, fakes) as camera:
        assert log == []  # nothing is read on open
        pair = camera.capture()
    assert pair.left.shape == (4, 6, 3)
    assert log == ["grab left", "grab right", "retrieve left", "retrieve right"] + [
        "release left",
        "release right",
    ]


def test_a_failed_retrieve_regrabs_both(monkeypatch: pytest.MonkeyPatch) -> None:
    log: list[str] = []
    fakes = {"L": FakeCapture("left", log), "R": FakeCapture("right", log)}
    fakes["R"].failed_retrieves = 1
    with fake_camera(monkeypatch, fakes) as camera:
        camera.capture()
    assert log[:8] == ["grab left", "grab right", "retrieve left", "retrieve right"] * 2


def test_backend_time_stamps_count_as_skew(monkeypatch: pytest.MonkeyPatch) -> None:
    log: list[str] = []
    fakes = {"L": FakeCapture("left", log, 1000.0), "R": FakeCapture("right", log, 1030.0)}
    with fake_camera(monkeypatch, fakes, grab_attempts=2) as camera:
        with pytest.raises(CaptureError) as error:
            camera.capture()
        assert "0.030 s apart" in str(error.value) and "max_skew_s: 0.01" in str(error.value)
        fakes["R"].pos_ms = 1002.0  # 2 ms apart: accepted
        assert camera.capture().right.shape == (4, 6, 3)
    assert "retrieve left" in log


def test_a_right_source_that_fails_to_open_releases_the_left(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    log: list[str] = []
    fakes = {"L": FakeCapture("left", log), "R": FakeCapture("right", log, opens=False)}
    with pytest.raises(ScannerError, match="hardware.camera.right: cannot open 'R'"):
        fake_camera(monkeypatch, fakes)
    assert log == ["release right", "release left"]


def test_close_releases_and_later_captures_are_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    log: list[str] = []
    fakes = {"L": FakeCapture("left", log), "R": FakeCapture("right", log)}
    camera = fake_camera(monkeypatch, fakes)
    camera.close()
    camera.close()
    assert log == ["release left", "release right"]
    with pytest.raises(RuntimeError, match="after close"):
        camera.capture()


def test_the_factory_refuses_other_camera_kinds() -> None:
    with pytest.raises(ScannerError, match="hardware.camera.kind: expected 'opencv'"):
        open_stereo_camera(CameraLinkConfig(kind="simulated"), None)

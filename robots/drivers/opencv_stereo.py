"""A stereo camera over OpenCV video capture: two sources, or one delivering side-by-side frames.

Sources are what `cv2.VideoCapture` opens: a device index, a device path, a URL, or an image
sequence (`rec/left_%04d.png`, opened with `cv2.CAP_IMAGES`), so a recorded scan replays through
the same driver as live cameras.

Synchronisation: the two cameras are not hardware-triggered, so both are `grab()`bed (the cheap
latch of the newest frame) before either is `retrieve()`d (the slow decode); decoding the left
image between the two grabs would push the right exposure later by a whole decode time. The
time between the two grabs' completions, or between the backend's frame time stamps where it
reports them, is the skew; a pair further apart than `max_skew_s` saw the arm (or the object) at
two different instants and is refused.

OpenCV behaviour this relies on (4.x, observed on 4.14): a source that cannot be opened gives
`isOpened() == False` rather than an exception (an image sequence whose first file, index 0 or
1, is missing counts as such); the end of a sequence or video is a `grab()` returning False;
`CAP_PROP_POS_MSEC` is 0 where the backend has no time stamps (image sequences).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from robots.drivers.interfaces import CaptureError, StereoCameraDriver, StereoImages
from robots.drivers.settings import CameraLinkConfig

# The seam through which sources are opened (tests put fake captures here).
_open: Callable[..., Any] = cv2.VideoCapture

_EXPECTED_SOURCE = (
    "expected a camera device index, a device path, a URL or an image-sequence pattern "
    "such as rec/left_%04d.png"
)


def _open_source(item: str, source: int | str) -> Any:
    """Open one source; a source that does not open is a user error naming the config item."""
    if isinstance(source, str) and "%" in source:
        capture = _open(source, cv2.CAP_IMAGES)
    else:
        capture = _open(source)
    if not capture.isOpened():
        capture.release()
        raise ScannerError(f"{item}: cannot open '{source}' ({_EXPECTED_SOURCE})")
    return capture


def _to_rgb(item: str, frame: np.ndarray) -> np.ndarray:
    """OpenCV delivers BGR (or grey / BGRA from image files); the product works in RGB uint8."""
    if frame.dtype != np.uint8:
        raise ScannerError(f"{item}: delivers {frame.dtype} images (expected 8-bit, uint8)")
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)


def _size(image: np.ndarray) -> str:
    return f"{image.shape[1]}x{image.shape[0]}"


class OpenCvStereoCamera(StereoCameraDriver):
    """`hardware.camera` of kind "opencv"; image_size: (width, height) in pixels that the
    calibration expects of each image, or None to accept what the cameras deliver."""

    def __init__(
        self, settings: CameraLinkConfig, image_size: tuple[int, int] | None = None
    ) -> None:
        if settings.kind != "opencv":
            raise ScannerError(f"hardware.camera.kind: expected 'opencv', got '{settings.kind}'")
        self._settings = settings
        self._image_size = image_size
        self._captures: list[Any] = []
        try:
            self._captures.append(_open_source("hardware.camera.left", settings.left))
            if not settings.side_by_side:
                assert settings.right is not None  # CameraLinkConfig enforces it
                self._captures.append(_open_source("hardware.camera.right", settings.right))
        except BaseException:
            self.close()
            raise
        # Nothing is read on open: a live camera's first frame would be stale by the time the
        # scan starts, and an image sequence would lose a recorded pair.

    def check_size(self) -> tuple[int, int]:
        """Grab one pair (consuming it) and check its size against the calibration's, so that a
        wrong camera mode is reported before anything moves; returns (width, height)."""
        pair = self.capture()
        return pair.left.shape[1], pair.left.shape[0]

    def capture(self) -> StereoImages:
        """Grab a pair, retrying failed or skewed grabs up to grab_attempts times in a row."""
        if not self._captures:
            raise RuntimeError("OpenCvStereoCamera.capture() after close()")
        attempts = self._settings.grab_attempts
        reason = ""
        for _ in range(attempts):
            result = self._try_capture()
            if isinstance(result, StereoImages):
                # Every pair, not only the first: the check is a shape comparison, and an image
                # of the wrong size would silently corrupt everything computed from it.
                self._check_sizes(result)
                return result
            reason = result
        raise CaptureError(f"{reason} ({attempts} attempts in a row)")

    def _try_capture(self) -> StereoImages | str:
        """One attempt: the pair, or why there is none (a reason is retried)."""
        if self._settings.side_by_side:
            (source,) = self._captures
            ok = source.grab()
            stamp_s = time.time()
            if not ok:
                return "hardware.camera.left: grab failed (no frame; end of a recording?)"
            ok, frame = source.retrieve()
            if not ok or frame is None:
                return "hardware.camera.left: retrieve failed after a good grab"
            width = frame.shape[1]
            if width % 2:
                raise ScannerError(
                    f"hardware.camera.left: delivers side-by-side frames {width} pixels wide "
                    "(expected an even width: two images side by side)"
                )
            rgb = _to_rgb("hardware.camera.left", frame)
            return StereoImages(rgb[:, : width // 2].copy(), rgb[:, width // 2 :].copy(), stamp_s)

        # Both grabs first, each timed at its completion; only then the retrieves (see above).
        left, right = self._captures
        ok_left = left.grab()
        done_left = time.monotonic()
        stamp_s = time.time()
        ok_right = right.grab()
        done_right = time.monotonic()
        for side, ok in (("left", ok_left), ("right", ok_right)):
            if not ok:
                return f"hardware.camera.{side}: grab failed (no frame; end of a recording?)"
        skew_s = abs(done_right - done_left)
        # Backends that stamp frames (e.g. V4L2 with driver time stamps) know when each frame was
        # exposed; the grab times only know when it arrived. 0 means "not reported".
        stamp_left_ms = float(left.get(cv2.CAP_PROP_POS_MSEC))
        stamp_right_ms = float(right.get(cv2.CAP_PROP_POS_MSEC))
        if stamp_left_ms > 0 and stamp_right_ms > 0:
            skew_s = max(skew_s, abs(stamp_left_ms - stamp_right_ms) / 1000.0)
        max_skew_s = self._settings.max_skew_s
        if skew_s > max_skew_s:
            return (
                f"left and right grabbed {skew_s:.3f} s apart "
                f"(hardware.camera.max_skew_s: {max_skew_s:g})"
            )
        images = []
        for side, source in (("left", left), ("right", right)):
            ok, frame = source.retrieve()
            if not ok or frame is None:
                return f"hardware.camera.{side}: retrieve failed after a good grab"
            images.append(_to_rgb(f"hardware.camera.{side}", frame))
        return StereoImages(images[0], images[1], stamp_s)

    def _check_sizes(self, pair: StereoImages) -> None:
        """A size mismatch is a configuration error (wrong camera mode or wrong calibration),
        not a transient failure: ScannerError, which the scan does not retry."""
        if self._image_size is not None:
            width, height = self._image_size
            expected = f"{width}x{height}"
            each_half = (
                " (each half of its side-by-side frames)" if self._settings.side_by_side else ""
            )
            for side, image in (("left", pair.left), ("right", pair.right)):
                if _size(image) != expected:
                    item = "left" if self._settings.side_by_side else side
                    raise ScannerError(
                        f"hardware.camera.{item}: delivers {_size(image)} images{each_half}, "
                        f"the calibration expects {expected}"
                    )
        elif pair.left.shape != pair.right.shape:
            raise ScannerError(
                f"hardware.camera.right: delivers {_size(pair.right)} images, the left camera "
                f"{_size(pair.left)} (expected the same size from both)"
            )

    def close(self) -> None:
        """Release the sources (idempotent)."""
        captures, self._captures = self._captures, []
        for source in captures:
            source.release()

    def __enter__(self) -> OpenCvStereoCamera:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()


def open_stereo_camera(
    settings: CameraLinkConfig, image_size: tuple[int, int] | None
) -> OpenCvStereoCamera:
    """The camera for a `hardware.camera` section of kind "opencv" (others are user errors)."""
    if settings.kind != "opencv":
        raise ScannerError(
            f"hardware.camera.kind: expected 'opencv' for an OpenCV camera, got '{settings.kind}'"
        )
    return OpenCvStereoCamera(settings, image_size)

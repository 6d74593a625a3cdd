"""One capture in memory (`Capture`) and the files of each capture format: what a capture's
folder holds and how it is read back, checked. A sensor kind (robots.sensors) names its
format (`Sensor.capture_format`); kinds may share one.

    stereo   left.png, right.png (the pair)
    rgbd     color.png, depth.png (uint16 counts of depth_scale_m metres)
    mono     image.png, optional mask.png and depth.png, and the view's own camera and X_WC
             in capture.yaml (an imported recording)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import CameraModelError, PinholeCamera


@dataclass(frozen=True, eq=False)
class Capture:
    """One capture and the robot state it was taken at (what `reconstruct` reads): a stereo
    pair (left, right), or an RGB-D capture (left: the colour image, right None, depth: uint16
    counts of depth_scale_m metres on the depth camera's grid), or a view of an imported
    recording (sensor mono: left the image, right None, its own `camera` and pose `X_WC`, an
    optional `mask`, uint8 0/255, 255 on the object, and an optional depth on the image's grid;
    q_rad is empty, no joints were recorded, and X_WF is the flange pose, or X_WC when the
    recording gave camera poses)."""

    pose_index: int
    pose_count: int
    q_rad: np.ndarray
    X_WF: np.ndarray
    stamp_s: float
    left: np.ndarray
    right: np.ndarray | None
    depth: np.ndarray | None = None
    depth_scale_m: float = 0.0
    mask: np.ndarray | None = None
    camera: PinholeCamera | None = None
    X_WC: np.ndarray | None = None

    def __post_init__(self) -> None:
        if (self.camera is None) != (self.X_WC is None):
            raise AssertionError("a mono capture has its camera and X_WC; others have neither")
        if self.camera is not None and self.right is not None:
            raise AssertionError("a mono capture has one image")
        for a in (self.q_rad, self.X_WF, self.left, self.right, self.depth, self.mask, self.X_WC):
            if a is not None:
                a.setflags(write=False)

    @property
    def sensor(self) -> str:
        if self.camera is not None:
            return "mono"
        return "stereo" if self.depth is None else "rgbd"

    @staticmethod
    def of(pose_index: int, pose_count: int, q_rad, X_WF, images) -> Capture:
        """The capture of what a camera driver delivered (StereoImages or RgbdImages)."""
        if hasattr(images, "depth"):
            return Capture(
                pose_index,
                pose_count,
                q_rad,
                X_WF,
                images.stamp_s,
                images.color,
                None,
                images.depth,
                float(images.depth_scale_m),
            )
        return Capture(
            pose_index, pose_count, q_rad, X_WF, images.stamp_s, images.left, images.right
        )


@dataclass(frozen=True, eq=False)
class CaptureHeader:
    """What every capture.yaml holds, already checked: its folder, the whole metadata, and the
    index, count, joints, flange pose, time stamp and image size."""

    folder: Path
    meta: dict
    index: int
    count: int
    q_rad: np.ndarray
    X_WF: np.ndarray
    stamp_s: float
    width: int
    height: int


@dataclass(frozen=True)
class CaptureFormat:
    """One capture format: its image files (key in capture.yaml -> (file name, image)), its
    own capture.yaml fields, and its reader; `joints_required`: False where a capture may have
    no joints (a recording's view)."""

    files: Callable[[Capture], dict[str, tuple[str, np.ndarray]]]
    read: Callable[[CaptureHeader], Capture]
    own_fields: Callable[[Capture], dict] = lambda capture: {}
    joints_required: bool = True


def _stereo_files(capture: Capture) -> dict:
    return {"left": ("left.png", capture.left), "right": ("right.png", capture.right)}


def _read_stereo(h: CaptureHeader) -> Capture:
    left, right = (
        _read_rgb(h.folder / str(h.meta.get(name, f"{name}.png")), h.width, h.height)
        for name in ("left", "right")
    )
    return Capture(h.index, h.count, h.q_rad, h.X_WF, h.stamp_s, left, right)


def _rgbd_files(capture: Capture) -> dict:
    return {"color": ("color.png", capture.left), "depth": ("depth.png", capture.depth)}


def _read_rgbd(h: CaptureHeader) -> Capture:
    color = _read_rgb(h.folder / str(h.meta.get("color", "color.png")), h.width, h.height)
    depth, scale = read_depth(h.folder, h.meta)
    return Capture(h.index, h.count, h.q_rad, h.X_WF, h.stamp_s, color, None, depth, scale)


def _mono_files(capture: Capture) -> dict:
    files = {"image": ("image.png", capture.left)}
    for key, image in (("mask", capture.mask), ("depth", capture.depth)):
        if image is not None:
            files[key] = (f"{key}.png", image)
    return files


def _mono_fields(capture: Capture) -> dict:
    return {"camera": mono_camera_to_dict(capture.camera), "X_WC": capture.X_WC.tolist()}


def mono_camera_to_dict(camera: PinholeCamera) -> dict:
    return {
        "K": camera.K.tolist(),
        "distortion": camera.distortion.tolist(),
        "width": camera.width,
        "height": camera.height,
    }


def mono_camera_from_dict(d, where: str) -> PinholeCamera:
    if not isinstance(d, dict) or any(k not in d for k in ("K", "distortion", "width", "height")):
        raise ScannerError(f"{where}: camera: expected K, distortion, width and height")
    w, h = d["width"], d["height"]
    if not (isinstance(w, int) and isinstance(h, int)) or isinstance(w, bool):
        raise ScannerError(f"{where}: camera: width and height must be whole pixels")
    try:
        return PinholeCamera(d["K"], d["distortion"], w, h)
    except CameraModelError as e:
        raise ScannerError(f"{where}: camera: {e}") from None


def _read_mono(h: CaptureHeader) -> Capture:
    """A view of an imported recording: its image, camera and X_WC, an optional mask and
    depth, each checked against the image size."""
    d, meta, width, height = h.folder, h.meta, h.width, h.height
    where = d / "capture.yaml"
    camera = mono_camera_from_dict(meta.get("camera"), str(where))
    if (camera.width, camera.height) != (width, height):
        raise ScannerError(
            f"{where}: camera is {camera.width}x{camera.height}, image_size {width}x{height}"
        )
    try:
        X_WC = np.array(meta["X_WC"], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise ScannerError(f"{where}: X_WC: expected a finite 4x4 matrix") from None
    if X_WC.shape != (4, 4) or not np.all(np.isfinite(X_WC)):
        raise ScannerError(f"{where}: X_WC: expected a finite 4x4 matrix")
    image = _read_rgb(d / str(meta.get("image", "image.png")), width, height)
    mask = None
    if "mask" in meta:
        path = d / str(meta["mask"])
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise ScannerError(f"{path}: missing or unreadable mask")
        if mask.shape != (height, width):
            raise ScannerError(
                f"{path}: mask is {mask.shape[1]}x{mask.shape[0]}, expected {width}x{height}"
            )
    depth, scale = (None, 0.0) if "depth" not in meta else read_depth(d, meta)
    return Capture(
        h.index, h.count, h.q_rad, h.X_WF, h.stamp_s, image, None, depth, scale, mask, camera, X_WC
    )


def _read_rgb(path: Path, width: int, height: int) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ScannerError(f"{path}: missing or unreadable image")
    if bgr.shape[:2] != (height, width):
        raise ScannerError(
            f"{path}: image is {bgr.shape[1]}x{bgr.shape[0]}, expected {width}x{height}"
        )
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def read_depth(folder: Path, meta: dict) -> tuple[np.ndarray, float]:
    """An RGB-D capture's depth counts and their unit, checked against its capture.yaml."""
    where = folder / "capture.yaml"
    scale = meta.get("depth_scale_m")
    if isinstance(scale, bool) or not isinstance(scale, int | float):
        raise ScannerError(
            f"{where}: depth_scale_m: expected the depth unit in metres, got {scale!r}"
        )
    if not (np.isfinite(scale) and scale > 0):
        raise ScannerError(f"{where}: depth_scale_m: expected a positive number, got {scale}")
    size = meta.get("depth_size")
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(n, int) for n in size)):
        raise ScannerError(f"{where}: depth_size: expected [width, height], got {size!r}")
    path = folder / str(meta.get("depth", "depth.png"))
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise ScannerError(f"{path}: missing or unreadable depth image")
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ScannerError(f"{path}: expected a 16-bit single-channel depth image")
    if depth.shape != (size[1], size[0]):
        raise ScannerError(
            f"{path}: depth image is {depth.shape[1]}x{depth.shape[0]}, expected "
            f"{size[0]}x{size[1]}"
        )
    return depth, float(scale)


# By the name capture.yaml's `sensor:` field gives (Capture.sensor).
CAPTURE_FORMATS = {
    "stereo": CaptureFormat(_stereo_files, _read_stereo),
    "rgbd": CaptureFormat(_rgbd_files, _read_rgbd),
    "mono": CaptureFormat(_mono_files, _read_mono, _mono_fields, joints_required=False),
}


def format_names() -> str:
    """'stereo', 'rgbd' or 'mono'."""
    names = [repr(n) for n in CAPTURE_FORMATS]
    return f"{', '.join(names[:-1])} or {names[-1]}"

"""OpenCV's stereo_calib files (intrinsics.yml, extrinsics.yml) to and from a StereoCamera,
through cv2.FileStorage (the layout is described in `reconstruction.calibration.exchange`)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import cv2
import numpy as np

from reconstruction.calibration.camera_files import (
    camera_from,
    distortion5,
    stereo_from,
)
from reconstruction.common.errors import ScannerError
from reconstruction.common.lengths import parse_length
from reconstruction.stereo.camera_model import StereoCamera
from reconstruction.stereo.rectification import compute_rectification

OPENCV_INTRINSICS = "intrinsics.yml"
OPENCV_EXTRINSICS = "extrinsics.yml"
OPENCV_FILES = (OPENCV_INTRINSICS, OPENCV_EXTRINSICS)
LENGTH_UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def parse_length_unit(text: str) -> float:
    """Metres per length unit: 'm', 'cm', 'mm', or a length (the board square size, for files
    in OpenCV's stereo_calib units): a number of metres, or with a unit (`25mm`)."""
    name = str(text).strip()
    if name in LENGTH_UNITS_M:
        return LENGTH_UNITS_M[name]
    try:
        return parse_length(name)
    except ScannerError as e:
        raise ScannerError(
            f"length unit '{text}': expected m, cm, mm or a length (the board square size for "
            f"files in board squares: a number of metres, or with a unit such as 25mm): {e}"
        ) from None


def _opencv_text(entries: list[tuple[str, object]], comments: list[str]) -> str:
    fs = cv2.FileStorage(".yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for comment in comments:
        fs.writeComment(comment)
    for key, value in entries:
        fs.write(key, value)
    return fs.releaseAndGetString()


def opencv_stereo_texts(stereo: StereoCamera) -> dict[str, str]:
    """{file name: FileStorage YAML} of intrinsics.yml and extrinsics.yml."""
    rect = compute_rectification(stereo)
    w, h = stereo.image_size
    intrinsics = _opencv_text(
        [
            ("M1", stereo.left.K),
            ("D1", stereo.left.distortion.reshape(1, 5)),
            ("M2", stereo.right.K),
            ("D2", stereo.right.distortion.reshape(1, 5)),
            ("image_width", int(w)),
            ("image_height", int(h)),
        ],
        ["M: camera matrix (px); D: k1 k2 p1 p2 k3; image size in px"],
    )
    extrinsics = _opencv_text(
        [
            ("R", stereo.R),
            ("T", stereo.T.reshape(3, 1)),
            ("R1", rect.R1),
            ("R2", rect.R2),
            ("P1", rect.P1),
            ("P2", rect.P2),
            ("Q", rect.Q),
            ("length_unit", "m"),
        ],
        [
            "x_right = R x_left + T (cv2.stereoCalibrate); T, P2 and Q in metres",
            "R1 R2 P1 P2 Q: cv2.stereoRectify, CALIB_ZERO_DISPARITY, alpha 0",
        ],
    )
    return {OPENCV_INTRINSICS: intrinsics, OPENCV_EXTRINSICS: extrinsics}


def write_opencv_stereo(stereo: StereoCamera, folder: Path) -> list[Path]:
    """intrinsics.yml and extrinsics.yml in `folder` (which must exist); their paths."""
    paths = []
    for name, text in opencv_stereo_texts(stereo).items():
        path = Path(folder) / name
        path.write_text(text)
        paths.append(path)
    return paths


def _read_bytes(path: Path, what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise ScannerError(f"{path}: cannot read {what} ({e.strerror})") from None


def _opencv_error_text(e: BaseException) -> str:
    """OpenCV's message without its source location, on one line."""
    text = " ".join(str(e.__cause__ or e).split())
    m = re.search(r"error: \(-?\d+:[^)]*\) (.*)", text)
    return m.group(1) if m else text


def _open_filestorage(path: Path) -> cv2.FileStorage:
    """The parsed FileStorage of `path`; read here (not by OpenCV) so that a missing or
    unreadable file gets the OS's reason rather than an OpenCV log line."""
    try:
        text = _read_bytes(path, "OpenCV file").decode("utf-8")
    except UnicodeDecodeError:
        raise ScannerError(f"{path}: not a text file (OpenCV FileStorage YAML expected)") from None
    if not text.lstrip().startswith("%YAML"):
        # From memory, OpenCV recognises YAML by this header only (from a file, by the name).
        text = "%YAML:1.0\n" + text
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as e:
        # The binding reports a parse failure as SystemError with the cv2.error as its cause.
        raise ScannerError(
            f"{path}: not an OpenCV FileStorage YAML file ({_opencv_error_text(e)})"
        ) from None
    if not fs.isOpened() or not fs.root().isMap():
        raise ScannerError(f"{path}: not an OpenCV FileStorage YAML file (expected a mapping)")
    return fs


def _opencv_matrix(fs: cv2.FileStorage, key: str, shapes, path: Path) -> np.ndarray:
    node = fs.getNode(key)
    if node.isNone():
        raise ScannerError(f"{path}: missing key '{key}'")
    m, reason = None, "expected !!opencv-matrix with rows, cols, dt and data"
    if node.isMap():
        try:
            m = node.mat()
        except cv2.error as e:
            reason = _opencv_error_text(e)
    if m is None:
        raise ScannerError(f"{path}: {key} is not an OpenCV matrix ({reason})")
    m = np.asarray(m, float)
    if m.ndim != 2:
        raise ScannerError(f"{path}: {key} has {m.shape[2]} channels, expected 1 (dt: d)")
    if shapes is not None and m.shape not in shapes:
        want = " or ".join(f"{r}x{c}" for r, c in shapes)
        raise ScannerError(f"{path}: {key} is {m.shape[0]}x{m.shape[1]}, expected {want}")
    if not np.all(np.isfinite(m)):
        raise ScannerError(f"{path}: {key} holds values that are not finite")
    return m


def _opencv_distortion(fs: cv2.FileStorage, key: str, path: Path) -> np.ndarray:
    d = _opencv_matrix(fs, key, None, path)
    if 1 not in d.shape:
        raise ScannerError(f"{path}: {key} is {d.shape[0]}x{d.shape[1]}, expected 1xN")
    return distortion5(d, f"{path}: {key}")


def _opencv_int(fs: cv2.FileStorage, key: str, path: Path) -> int | None:
    node = fs.getNode(key)
    if node.isNone():
        return None
    value = node.real() if (node.isInt() or node.isReal()) else math.nan
    if not (math.isfinite(value) and value == int(value) and value > 0):
        raise ScannerError(f"{path}: {key} must be a positive whole number of pixels")
    return int(value)


def _opencv_image_size(
    fs: cv2.FileStorage, path: Path, given: tuple[int, int] | None
) -> tuple[int, int]:
    w, h = _opencv_int(fs, "image_width", path), _opencv_int(fs, "image_height", path)
    if (w is None) != (h is None):
        raise ScannerError(f"{path}: has one of image_width and image_height, not both")
    if w is None:
        if given is None:
            raise ScannerError(
                f"{path}: no image_width/image_height (OpenCV's stereo_calib sample writes "
                "none): give the image size (--image-size WxH)"
            )
        return given
    if given is not None and tuple(given) != (w, h):
        raise ScannerError(
            f"{path}: image_width/image_height say {w}x{h}, the given image size is "
            f"{given[0]}x{given[1]}"
        )
    return (w, h)


def _opencv_unit_m(fs: cv2.FileStorage, path: Path, given_m: float | None) -> float:
    node = fs.getNode("length_unit")
    if node.isNone():
        return 1.0 if given_m is None else given_m
    text = node.string() if node.isString() else str(node.real())
    try:
        in_file = parse_length_unit(text)
    except ScannerError as e:
        raise ScannerError(f"{path}: length_unit: {e}") from None
    if given_m is not None and not math.isclose(given_m, in_file, rel_tol=1e-12):
        raise ScannerError(
            f"{path}: length_unit says '{text}' ({in_file} m), the given length unit is {given_m} m"
        )
    return in_file


def read_opencv_stereo(
    folder: Path,
    image_size: tuple[int, int] | None = None,
    length_unit_m: float | None = None,
) -> StereoCamera:
    """The StereoCamera of intrinsics.yml and extrinsics.yml in `folder`.

    image_size (w, h px): needed when intrinsics.yml has no image_width/image_height (must
    agree when it has). length_unit_m: metres per unit of T when extrinsics.yml has no
    length_unit (must agree when it has); default metres. R1, R2, P1, P2 and Q are not read:
    they follow from the rest (and are recomputed for the image size where they are used).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ScannerError(
            f"{folder}: not a folder (expected one holding {', '.join(OPENCV_FILES)})"
        )
    intrinsics = folder / OPENCV_INTRINSICS
    extrinsics = folder / OPENCV_EXTRINSICS
    fs_i = _open_filestorage(intrinsics)
    fs_e = _open_filestorage(extrinsics)
    size = _opencv_image_size(fs_i, intrinsics, image_size)
    left = camera_from(
        _opencv_matrix(fs_i, "M1", [(3, 3)], intrinsics),
        _opencv_distortion(fs_i, "D1", intrinsics),
        size,
        f"{intrinsics}: M1/D1",
    )
    right = camera_from(
        _opencv_matrix(fs_i, "M2", [(3, 3)], intrinsics),
        _opencv_distortion(fs_i, "D2", intrinsics),
        size,
        f"{intrinsics}: M2/D2",
    )
    R = _opencv_matrix(fs_e, "R", [(3, 3)], extrinsics)
    T = _opencv_matrix(fs_e, "T", [(3, 1), (1, 3)], extrinsics).ravel()
    unit_m = _opencv_unit_m(fs_e, extrinsics, length_unit_m)
    return stereo_from(left, right, R, T * unit_m, f"{extrinsics}: R/T")

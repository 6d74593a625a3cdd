"""ROS camera_info files (left.yaml, right.yaml) to and from a StereoCamera (the layout is
described in `reconstruction.calibration.exchange`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from reconstruction.calibration.camera_files import camera_from, distortion5, stereo_from
from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml
from reconstruction.stereo.camera_model import StereoCamera
from reconstruction.stereo.rectification import compute_rectification

ROS_LEFT = "left.yaml"
ROS_RIGHT = "right.yaml"
ROS_FILES = (ROS_LEFT, ROS_RIGHT)
# ROS distortion models whose coefficients start with OpenCV's k1 k2 p1 p2 k3.
ROS_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")


def _ros_matrix(rows: int, cols: int, values: np.ndarray) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.ravel(values)]}


def camera_info_dicts(
    stereo: StereoCamera, camera_names: tuple[str, str] = ("left", "right")
) -> dict[str, dict]:
    """{file name: camera_info mapping} of the left and right camera.

    rectification_matrix and projection_matrix come from the product's rectification, so the
    rectified images ROS computes match ours; the right projection matrix holds
    Tx = -fx' * baseline (baseline in metres).
    """
    rect = compute_rectification(stereo)
    w, h = stereo.image_size
    infos = {}
    for name, camera, R_rect, P, camera_name in (
        (ROS_LEFT, stereo.left, rect.R1, rect.P1, camera_names[0]),
        (ROS_RIGHT, stereo.right, rect.R2, rect.P2, camera_names[1]),
    ):
        infos[name] = {
            "image_width": int(w),
            "image_height": int(h),
            "camera_name": camera_name,
            "camera_matrix": _ros_matrix(3, 3, camera.K),
            "distortion_model": "plumb_bob",
            "distortion_coefficients": _ros_matrix(1, 5, camera.distortion),
            "rectification_matrix": _ros_matrix(3, 3, R_rect),
            "projection_matrix": _ros_matrix(3, 4, P),
        }
    return infos


def write_ros_camera_info(
    stereo: StereoCamera, folder: Path, camera_names: tuple[str, str] = ("left", "right")
) -> list[Path]:
    """left.yaml and right.yaml in `folder` (which must exist); their paths."""
    paths = []
    for name, info in camera_info_dicts(stereo, camera_names).items():
        path = Path(folder) / name
        # Flow style for the data lists only, as camera_calibration_parsers writes them; floats
        # are written with repr, so they read back bit for bit.
        path.write_text(yaml.safe_dump(info, sort_keys=False, default_flow_style=None, width=1000))
        paths.append(path)
    return paths


def _ros_field(d: dict, key: str, path: Path):
    if key not in d:
        raise ScannerError(f"{path}: missing key '{key}'")
    return d[key]


def _ros_int(d: dict, key: str, path: Path) -> int:
    value = _ros_field(d, key, path)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ScannerError(f"{path}: {key} must be a positive whole number, got {value!r}")
    return value


def _ros_matrix_field(d: dict, key: str, rows: int, cols: int | None, path: Path) -> np.ndarray:
    node = _ros_field(d, key, path)
    if not isinstance(node, dict) or not {"rows", "cols", "data"} <= node.keys():
        raise ScannerError(f"{path}: {key} must be a mapping with rows, cols and data")
    r, c, data = node["rows"], node["cols"], node["data"]
    if not all(isinstance(n, int) and not isinstance(n, bool) for n in (r, c)):
        raise ScannerError(f"{path}: {key}: rows and cols must be whole numbers")
    if r != rows or (cols is not None and c != cols) or c <= 0:
        want = f"{rows}x{cols}" if cols is not None else f"{rows}xN"
        raise ScannerError(f"{path}: {key} is {r}x{c}, expected {want}")
    if not isinstance(data, list) or len(data) != r * c:
        n = len(data) if isinstance(data, list) else "no list of"
        raise ScannerError(f"{path}: {key} has {n} numbers in data, expected {r * c}")
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in data):
        raise ScannerError(f"{path}: {key}: data must be numbers")
    m = np.array(data, float).reshape(r, c)
    if not np.all(np.isfinite(m)):
        raise ScannerError(f"{path}: {key} holds values that are not finite")
    return m


@dataclass(frozen=True, eq=False)
class _CameraInfo:
    size: tuple[int, int]
    K: np.ndarray
    distortion: np.ndarray
    R_rect: np.ndarray
    P: np.ndarray


def _read_camera_info(path: Path) -> _CameraInfo:
    d = read_yaml(path, "ROS camera_info")
    if not isinstance(d, dict):
        raise ScannerError(f"{path}: not a ROS camera_info file (expected a mapping)")
    size = (_ros_int(d, "image_width", path), _ros_int(d, "image_height", path))
    model = _ros_field(d, "distortion_model", path)
    if model not in ROS_DISTORTION_MODELS:
        raise ScannerError(
            f"{path}: distortion_model is {model!r}, expected {' or '.join(ROS_DISTORTION_MODELS)}"
        )
    D = _ros_matrix_field(d, "distortion_coefficients", 1, None, path)
    return _CameraInfo(
        size,
        _ros_matrix_field(d, "camera_matrix", 3, 3, path),
        distortion5(D, f"{path}: distortion_coefficients"),
        _ros_matrix_field(d, "rectification_matrix", 3, 3, path),
        _ros_matrix_field(d, "projection_matrix", 3, 4, path),
    )


def read_ros_camera_info(folder: Path) -> StereoCamera:
    """The StereoCamera of left.yaml and right.yaml in `folder` (see the module docstring for
    how R and T follow from the rectification and the right projection matrix)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ScannerError(f"{folder}: not a folder (expected one holding {', '.join(ROS_FILES)})")
    left_path, right_path = folder / ROS_LEFT, folder / ROS_RIGHT
    left, right = _read_camera_info(left_path), _read_camera_info(right_path)
    if left.size != right.size:
        raise ScannerError(
            f"{right_path}: image_width/image_height {right.size[0]}x{right.size[1]} differ "
            f"from {left_path}'s {left.size[0]}x{left.size[1]}"
        )
    for path, info in ((left_path, left), (right_path, right)):
        if not np.allclose(info.R_rect @ info.R_rect.T, np.eye(3), atol=1e-6):
            raise ScannerError(f"{path}: rectification_matrix is not a rotation matrix")
    if left.P[0, 3] != 0 or left.P[1, 3] != 0:
        raise ScannerError(
            f"{left_path}: projection_matrix has Tx/Ty {left.P[0, 3]}/{left.P[1, 3]}; the "
            "left camera of a stereo pair has 0 there"
        )
    P = right.P
    if P[0, 0] <= 0 or P[1, 1] <= 0:
        raise ScannerError(f"{right_path}: projection_matrix focal lengths must be positive")
    if P[0, 3] >= 0:
        raise ScannerError(
            f"{right_path}: projection_matrix Tx is {P[0, 3]}; the right camera of a stereo "
            "pair has -fx' * baseline there (a negative number), these are not a stereo pair"
        )
    p_rect = np.array([P[0, 3] / P[0, 0], P[1, 3] / P[1, 1], 0.0])
    R = right.R_rect.T @ left.R_rect
    T = right.R_rect.T @ p_rect
    return stereo_from(
        camera_from(left.K, left.distortion, left.size, str(left_path)),
        camera_from(right.K, right.distortion, right.size, str(right_path)),
        R,
        T,
        str(folder),
    )

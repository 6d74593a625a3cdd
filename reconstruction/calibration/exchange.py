"""The calibration in the files OpenCV and ROS users already have: pure functions between a
StereoCamera (or X_FC) and those files.

OpenCV (the layout of OpenCV's `samples/cpp/stereo_calib.cpp`, written through cv2.FileStorage):

    intrinsics.yml  M1 D1 M2 D2 (3x3 K and 1x5 k1 k2 p1 p2 k3 of the left and right camera),
                    image_width image_height (as OpenCV's single-camera calibration sample names
                    them; stereo_calib writes no image size)
    extrinsics.yml  R T (cv2.stereoCalibrate: x_right = R x_left + T, i.e. X_RC; our
                    StereoCamera.R and .T as they are), R1 R2 P1 P2 Q (cv2.stereoRectify),
                    length_unit

  stereo_calib's T (and P2, Q) are in units of its square size (`-s`, default 1: board squares);
  ours are in metres and say so (`length_unit: m`). Reading takes the unit from that key, else
  from the caller, else assumes metres.

ROS (`sensor_msgs/CameraInfo` as camera_calibration_parsers writes it, one file per camera):

    left.yaml, right.yaml  image_width image_height camera_name camera_matrix
                           distortion_model (plumb_bob) distortion_coefficients
                           rectification_matrix projection_matrix  ({rows, cols, data})

  The right camera's projection matrix carries Tx = -fx' * baseline (metres, REP 104 and the
  CameraInfo message). Reading rebuilds R, T from the rectification: both rectified frames share
  one orientation (R_rect_C = R1, R_rect_R = R2) and the right one sits at (Tx / fx', Ty / fy', 0)
  in the left one, so R = R2^T R1 and T = R2^T (Tx / fx', Ty / fy', 0).

Hand-eye as a ROS static transform (hand_eye_tf.yaml): X_FC is the pose of the child frame (the
left optical frame C: z forward, x right, y down, what REP 103 suffixes `_optical`) in the parent
frame (the flange F, ROS-Industrial's `tool0`); translation in metres and the unit quaternion
(qx, qy, qz, qw) with qw >= 0, plus the `static_transform_publisher` command lines. Reading also
takes easy_handeye's files (`transformation: {x, y, z, qx, qy, qz, qw}`) and easy_handeye2's
(`transform: {translation: {x, y, z}, rotation: {x, y, z, w}}`).

Every reader raises ScannerError naming the file and the key.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from reconstruction.camera_model import CameraModelError, PinholeCamera, StereoCamera
from reconstruction.errors import ScannerError
from reconstruction.stereo.rectification import compute_rectification
from reconstruction.transforms import check_pose, make_pose
from reconstruction.yaml_files import read_yaml

OPENCV_INTRINSICS = "intrinsics.yml"
OPENCV_EXTRINSICS = "extrinsics.yml"
OPENCV_FILES = (OPENCV_INTRINSICS, OPENCV_EXTRINSICS)
ROS_LEFT = "left.yaml"
ROS_RIGHT = "right.yaml"
ROS_FILES = (ROS_LEFT, ROS_RIGHT)
HAND_EYE_TF = "hand_eye_tf.yaml"

LENGTH_UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
# OpenCV's distortion vector lengths (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]); the
# product's model has the first five, so longer vectors are taken only when the rest is zero.
OPENCV_DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
# ROS distortion models whose coefficients start with OpenCV's k1 k2 p1 p2 k3.
ROS_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")
# ROS names: a letter first, then letters, digits and underscores, '/' between name parts; tf2
# refuses frame ids that start with '/'.
ROS_FRAME_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*")
# Files print quaternions rounded (four decimals leave the length off by 1e-4 at most); further
# off than this, the four numbers are not a rotation.
QUATERNION_NORM_TOLERANCE = 1e-3


def parse_length_unit(text: str) -> float:
    """Metres per length unit: 'm', 'cm', 'mm', or a positive number of metres (the board
    square size, for files in OpenCV's stereo_calib units)."""
    name = str(text).strip()
    if name in LENGTH_UNITS_M:
        return LENGTH_UNITS_M[name]
    try:
        value = float(name)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ScannerError(
            f"length unit '{text}': expected m, cm, mm or a positive number of metres (the "
            "board square size for files in board squares)"
        )
    return value


def _distortion5(values: np.ndarray, where: str) -> np.ndarray:
    d = np.asarray(values, float).ravel()
    if len(d) not in OPENCV_DISTORTION_LENGTHS:
        raise ScannerError(
            f"{where}: expected {', '.join(map(str, OPENCV_DISTORTION_LENGTHS))} distortion "
            f"coefficients, got {len(d)}"
        )
    if np.any(d[5:] != 0):
        raise ScannerError(
            f"{where}: coefficients beyond k1 k2 p1 p2 k3 are not zero ({d[5:].tolist()}); the "
            "camera model here has k1 k2 p1 p2 k3 only, recalibrate without the rational or "
            "thin-prism terms"
        )
    return np.concatenate([d[:5], np.zeros(5 - min(len(d), 5))])


def _stereo(left: PinholeCamera, right: PinholeCamera, R, T, where: str) -> StereoCamera:
    try:
        return StereoCamera(left, right, R, T)
    except CameraModelError as e:
        raise ScannerError(f"{where}: {e}") from None


def _camera(K, distortion, size: tuple[int, int], where: str) -> PinholeCamera:
    try:
        return PinholeCamera(K, distortion, int(size[0]), int(size[1]))
    except CameraModelError as e:
        raise ScannerError(f"{where}: {e}") from None


# ------------------------------------------------------------------------------------ OpenCV
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
    return _distortion5(d, f"{path}: {key}")


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
    left = _camera(
        _opencv_matrix(fs_i, "M1", [(3, 3)], intrinsics),
        _opencv_distortion(fs_i, "D1", intrinsics),
        size,
        f"{intrinsics}: M1/D1",
    )
    right = _camera(
        _opencv_matrix(fs_i, "M2", [(3, 3)], intrinsics),
        _opencv_distortion(fs_i, "D2", intrinsics),
        size,
        f"{intrinsics}: M2/D2",
    )
    R = _opencv_matrix(fs_e, "R", [(3, 3)], extrinsics)
    T = _opencv_matrix(fs_e, "T", [(3, 1), (1, 3)], extrinsics).ravel()
    unit_m = _opencv_unit_m(fs_e, extrinsics, length_unit_m)
    return _stereo(left, right, R, T * unit_m, f"{extrinsics}: R/T")


# --------------------------------------------------------------------------------------- ROS
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
        _distortion5(D, f"{path}: distortion_coefficients"),
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
    return _stereo(
        _camera(left.K, left.distortion, left.size, str(left_path)),
        _camera(right.K, right.distortion, right.size, str(right_path)),
        R,
        T,
        str(folder),
    )


# ------------------------------------------------------------------------- static transform
def require_ros_frame(name: str, what: str) -> str:
    if not isinstance(name, str) or not ROS_FRAME_PATTERN.fullmatch(name):
        raise ScannerError(
            f"{what} '{name}': not a ROS frame name (a letter, then letters, digits or '_', "
            "'/' between parts)"
        )
    return name


@dataclass(frozen=True)
class StaticTransform:
    """A pose as tf2 publishes it: the child frame's pose in the parent frame.

    translation_m: position of the child origin in the parent (m). quaternion_xyzw: its
    orientation (qx, qy, qz, qw), unit length, qw >= 0.
    """

    parent_frame: str
    child_frame: str
    translation_m: tuple[float, float, float]
    quaternion_xyzw: tuple[float, float, float, float]

    def __post_init__(self) -> None:
        require_ros_frame(self.parent_frame, "parent frame")
        require_ros_frame(self.child_frame, "child frame")
        if self.parent_frame == self.child_frame:
            raise ScannerError(f"parent and child frame are both '{self.parent_frame}'")

    @property
    def X_PC(self) -> np.ndarray:
        """Pose of the child frame in the parent frame (4x4, m)."""
        return make_pose(Rotation.from_quat(self.quaternion_xyzw).as_matrix(), self.translation_m)

    def _numbers(self) -> list[str]:
        # repr: the shortest text that reads back as the same double.
        return [repr(float(v)) for v in (*self.translation_m, *self.quaternion_xyzw)]

    def ros1_command(self) -> str:
        return " ".join(
            [
                "rosrun tf2_ros static_transform_publisher",
                *self._numbers(),
                self.parent_frame,
                self.child_frame,
            ]
        )

    def ros1_launch(self) -> str:
        args = " ".join([*self._numbers(), self.parent_frame, self.child_frame])
        return (
            '<node pkg="tf2_ros" type="static_transform_publisher" '
            f'name="{self.child_frame.replace("/", "_")}_in_{self.parent_frame.replace("/", "_")}"'
            f' args="{args}" />'
        )

    def ros2_command(self) -> str:
        flags = ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw")
        pairs = [f"{f} {v}" for f, v in zip(flags, self._numbers())]
        return " ".join(
            [
                "ros2 run tf2_ros static_transform_publisher",
                *pairs,
                f"--frame-id {self.parent_frame}",
                f"--child-frame-id {self.child_frame}",
            ]
        )


def static_transform(
    X_FC: np.ndarray, parent_frame: str = "tool0", child_frame: str = "camera_optical_frame"
) -> StaticTransform:
    """X_FC (left optical frame C in the flange F) as the static transform parent -> child."""
    X_FC = check_pose(X_FC, "X_FC")
    q = Rotation.from_matrix(X_FC[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q  # q and -q are one rotation; qw >= 0 makes the numbers unique
    return StaticTransform(
        parent_frame,
        child_frame,
        tuple(float(v) for v in X_FC[:3, 3]),
        tuple(float(v) for v in q),
    )


def static_transform_text(tf: StaticTransform) -> str:
    """hand_eye_tf.yaml: the transform (easy_handeye's key names) and the commands that
    publish it."""
    t, q = tf.translation_m, tf.quaternion_xyzw
    body = {
        "parent_frame": tf.parent_frame,
        "child_frame": tf.child_frame,
        "transformation": {
            "x": t[0],
            "y": t[1],
            "z": t[2],
            "qx": q[0],
            "qy": q[1],
            "qz": q[2],
            "qw": q[3],
        },
        "ros1_command": tf.ros1_command(),
        "ros1_launch": tf.ros1_launch(),
        "ros2_command": tf.ros2_command(),
    }
    header = (
        "# Hand-eye calibration X_FC as a ROS static transform: the pose of child_frame (the left\n"
        "# camera's optical frame: z forward, x right, y down) in parent_frame (the flange).\n"
        "# x y z in metres; qx qy qz qw a unit quaternion (qw >= 0).\n"
    )
    return header + yaml.safe_dump(body, sort_keys=False, width=1000)


def write_static_transform(tf: StaticTransform, folder: Path) -> list[Path]:
    """hand_eye_tf.yaml in `folder` (which must exist); its path in a list, like the others."""
    path = Path(folder) / HAND_EYE_TF
    path.write_text(static_transform_text(tf))
    return [path]


def _numbers_of(node, keys: tuple[str, ...], where: str, path: Path) -> list[float]:
    if not isinstance(node, dict):
        raise ScannerError(f"{path}: {where} must be a mapping with {', '.join(keys)}")
    values = []
    for k in keys:
        if k not in node:
            raise ScannerError(f"{path}: missing key '{where}.{k}'")
        v = node[k]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ScannerError(f"{path}: {where}.{k} must be a finite number, got {v!r}")
        values.append(float(v))
    return values


def read_hand_eye(path: Path) -> np.ndarray:
    """X_FC (4x4, m) from a static transform file: ours (hand_eye_tf.yaml), easy_handeye's or
    easy_handeye2's eye-in-hand result."""
    path = Path(path)
    d = read_yaml(path, "hand-eye transform")
    if not isinstance(d, dict):
        raise ScannerError(f"{path}: not a hand-eye transform file (expected a mapping)")
    params = d.get("parameters")
    if isinstance(params, dict) and (
        params.get("eye_on_hand") is False
        or params.get("calibration_type") not in (None, "eye_in_hand")
    ):
        raise ScannerError(
            f"{path}: an eye-on-base calibration (camera in the robot base), not a camera on "
            "the flange"
        )
    if "transformation" in d:
        values = _numbers_of(
            d["transformation"], ("x", "y", "z", "qx", "qy", "qz", "qw"), "transformation", path
        )
        p, q = values[:3], values[3:]
    elif "transform" in d:
        node = d["transform"]
        if not isinstance(node, dict):
            raise ScannerError(f"{path}: transform must be a mapping with translation, rotation")
        p = _numbers_of(node.get("translation"), ("x", "y", "z"), "transform.translation", path)
        q = _numbers_of(node.get("rotation"), ("x", "y", "z", "w"), "transform.rotation", path)
    else:
        raise ScannerError(f"{path}: missing key 'transformation' (x y z qx qy qz qw)")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1) > QUATERNION_NORM_TOLERANCE:
        raise ScannerError(
            f"{path}: the quaternion (qx, qy, qz, qw) has length {norm:.6f}, expected 1"
        )
    return make_pose(Rotation.from_quat(q).as_matrix(), p)

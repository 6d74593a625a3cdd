"""Stereo camera model: per-camera intrinsics and distortion, left->right extrinsics; YAML I/O.

Conventions (OpenCV): pixel (u, v) with u right and v down; optical frame +z forward, +x right,
+y down. `R`, `T` are OpenCV's stereoCalibrate outputs: a point p_C in the LEFT camera frame is
p_R = R @ p_C + T in the RIGHT camera frame, i.e. (R, T) is the pose X_RC. For a rig whose right
camera sits at +b along the left camera's x axis, T = (-b, 0, 0).

File layout (YAML, SI units, one key per quantity so a person can read and edit it):

    schema: scanner.stereo_camera/1
    image_size: [width_px, height_px]
    left:  {K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], distortion: [k1, k2, p1, p2, k3]}
    right: {K: ..., distortion: ...}
    R: [[...], [...], [...]]          # rotation left -> right (X_RC)
    T: [tx, ty, tz]                   # metres
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose
from reconstruction.common.yaml_files import read_yaml

SCHEMA = "scanner.stereo_camera/1"


class CameraModelError(ScannerError):
    """A camera model file or record is malformed; the message names the field."""


def _frozen(a, shape: tuple[int, ...], name: str) -> np.ndarray:
    try:
        arr = np.array(a, dtype=float)
    except (TypeError, ValueError):
        raise CameraModelError(f"{name}: expected numbers of shape {shape}, got {a!r}") from None
    if arr.shape != shape:
        raise CameraModelError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CameraModelError(f"{name}: values must be finite")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """One camera: 3x3 intrinsics K (pixels), OpenCV distortion (k1, k2, p1, p2, k3), image size."""

    K: np.ndarray
    distortion: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", _frozen(self.K, (3, 3), "K"))
        object.__setattr__(self, "distortion", _frozen(self.distortion, (5,), "distortion"))
        if self.width <= 0 or self.height <= 0:
            raise CameraModelError(f"image size must be positive, got {self.width}x{self.height}")
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise CameraModelError("K: focal lengths must be positive")

    @property
    def focal_px(self) -> float:
        return float(self.K[0, 0])


@dataclass(frozen=True, eq=False)
class StereoCamera:
    """A calibrated stereo pair; (R, T) is X_RC as returned by cv2.stereoCalibrate."""

    left: PinholeCamera
    right: PinholeCamera
    R: np.ndarray
    T: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", _frozen(self.R, (3, 3), "R"))
        object.__setattr__(self, "T", _frozen(self.T, (3,), "T"))
        if (self.left.width, self.left.height) != (self.right.width, self.right.height):
            raise CameraModelError("left and right image sizes differ")
        if not np.allclose(self.R @ self.R.T, np.eye(3), atol=1e-6):
            raise CameraModelError("R: not a rotation matrix")
        if self.baseline_m <= 0:
            raise CameraModelError(f"T: baseline must be positive, got {self.baseline_m} m")
        # Matching searches along +x of the rectified rows: the right camera must sit to the
        # right of the left one (a swapped or vertical rig would give no matches at all).
        p_CR = self.X_CR[:3, 3]
        if p_CR[0] <= 0 or abs(p_CR[0]) < np.abs(p_CR[1:]).max():
            raise CameraModelError(
                f"T: the baseline along the left camera's +x axis must be positive (right camera "
                f"to the right); T = {self.T.tolist()} m puts the right camera at "
                f"{p_CR.tolist()} m in the left camera frame"
            )

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T))

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.left.width, self.left.height)

    @property
    def X_CR(self) -> np.ndarray:
        """Pose of the right camera in the left camera frame (4x4)."""
        return invert(make_pose(self.R, self.T))

    def eye_centres_W(self, X_WC: np.ndarray) -> np.ndarray:
        """Left and right camera centres (2, 3) in W, the left camera at X_WC: what a view
        sees is what both of them see."""
        return np.stack([X_WC[:3, 3], (X_WC @ self.X_CR)[:3, 3]])


def project_points(camera: PinholeCamera, p_S: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of points p_S (N, 3) in the camera's optical frame S, through OpenCV's
    k1 k2 p1 p2 k3 distortion (what cv2.projectPoints computes, vectorised)."""
    x = p_S[:, 0] / p_S[:, 2]
    y = p_S[:, 1] / p_S[:, 2]
    k1, k2, p1, p2, k3 = camera.distortion
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = camera.K
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)


@dataclass(frozen=True)
class StereoDesign:
    """A stereo rig as designed (what a configuration gives): image size, focal length,
    baseline along the left camera's +x axis and OpenCV distortion, both cameras alike.
    Defaults: the Bumblebee-like wrist rig of the SDU report."""

    width_px: int = integer(1280, minimum=16)
    height_px: int = integer(960, minimum=16)
    focal_px: float = positive(1320.0)
    baseline_m: float = positive(0.12)
    distortion: tuple[float, float, float, float, float] = (-0.42, 0.19, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        check_fields("camera", self)

    def stereo_camera(self) -> StereoCamera:
        return default_stereo_camera(
            self.width_px, self.height_px, self.focal_px, self.baseline_m, self.distortion
        )


def default_stereo_camera(
    width: int = 1280,
    height: int = 960,
    focal_px: float = 1320.0,
    baseline_m: float = 0.12,
    distortion: tuple[float, ...] = (-0.42, 0.19, 0.0, 0.0, 0.0),
) -> StereoCamera:
    """Bumblebee-like rig from the SDU report: f ~1320 px, b 0.12 m, k1 -0.42, k2 0.19."""
    K = np.array([[focal_px, 0, width / 2], [0, focal_px, height / 2], [0, 0, 1]])
    cam = PinholeCamera(K, np.array(distortion), width, height)
    return StereoCamera(cam, cam, np.eye(3), np.array([-baseline_m, 0.0, 0.0]))


def _camera_to_dict(cam: PinholeCamera) -> dict:
    return {"K": cam.K.tolist(), "distortion": cam.distortion.tolist()}


def stereo_camera_to_dict(model: StereoCamera) -> dict:
    return {
        "schema": SCHEMA,
        "image_size": [model.left.width, model.left.height],
        "left": _camera_to_dict(model.left),
        "right": _camera_to_dict(model.right),
        "R": model.R.tolist(),
        "T": model.T.tolist(),
    }


def _require(d: dict, key: str, where: str):
    if not isinstance(d, dict) or key not in d:
        raise CameraModelError(f"{where}: missing key '{key}'")
    return d[key]


def stereo_camera_from_dict(d: dict, where: str = "camera model") -> StereoCamera:
    schema = _require(d, "schema", where)
    if schema != SCHEMA:
        raise CameraModelError(f"{where}: schema is '{schema}', expected '{SCHEMA}'")
    size = _require(d, "image_size", where)
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(n, int) for n in size)):
        raise CameraModelError(f"{where}: image_size must be [width, height] in pixels")
    try:
        cams = []
        for side in ("left", "right"):
            c = _require(d, side, where)
            cams.append(
                PinholeCamera(
                    _require(c, "K", f"{where}.{side}"),
                    _require(c, "distortion", f"{where}.{side}"),
                    int(size[0]),
                    int(size[1]),
                )
            )
        return StereoCamera(cams[0], cams[1], _require(d, "R", where), _require(d, "T", where))
    except CameraModelError as e:
        raise CameraModelError(f"{where}: {e}") from None


def save_stereo_camera(model: StereoCamera, path: Path) -> None:
    Path(path).write_text(yaml.safe_dump(stereo_camera_to_dict(model), sort_keys=False))


def load_stereo_camera(path: Path) -> StereoCamera:
    return stereo_camera_from_dict(read_yaml(path, "camera model"), str(path))

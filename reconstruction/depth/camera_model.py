"""An RGB-D device as the software believes it: a colour camera, a depth camera beside it, the
depth unit and the range it measures.

Frames: C is the colour camera's optical frame (the frame hand-eye calibration finds from the
colour images, so X_WC = X_WF @ X_FC as for the stereo pair's left camera); D is the depth
camera's optical frame, at X_CD in C (the device's depth-to-colour extrinsics, inverted). A
device whose SDK aligns depth to colour (RealSense `rs.align`) has depth == colour and X_CD = I.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.transforms import check_pose
from reconstruction.common.yaml_files import read_yaml
from reconstruction.stereo.camera_model import (
    CameraModelError,
    PinholeCamera,
    StereoCamera,
    stereo_camera_from_dict,
    stereo_camera_to_dict,
)

SCHEMA = "scanner.rgbd_camera/1"


@dataclass(frozen=True, eq=False)
class RgbdCamera:
    """color, depth: the two cameras' intrinsics and image sizes; X_CD (4x4): the depth frame in
    the colour frame; depth_scale_m: metres per depth count (the device's depth unit, times a
    calibrated correction); min/max_depth_m: the range the device reports;
    depth_baseline_m: the baseline of its depth imagers (0: not known; its noise grows as
    z^2 / (f b)); depth_correction: the factor calibration found between the depth the device
    reports and the true one (a depth-scale error), applied to every depth."""

    color: PinholeCamera
    depth: PinholeCamera
    X_CD: np.ndarray
    depth_scale_m: float
    min_depth_m: float
    max_depth_m: float
    depth_baseline_m: float = 0.0
    depth_correction: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "X_CD", check_pose(self.X_CD, "rgbd camera X_CD"))
        self.X_CD.setflags(write=False)
        if not (np.isfinite(self.depth_scale_m) and self.depth_scale_m > 0):
            raise CameraModelError(
                f"depth_scale_m: expected a positive number, got {self.depth_scale_m}"
            )
        if not (np.isfinite(self.depth_correction) and 0.5 < self.depth_correction < 2.0):
            raise CameraModelError(
                f"depth_correction: expected a factor near 1, got {self.depth_correction}"
            )
        if not 0 < self.min_depth_m < self.max_depth_m:
            raise CameraModelError(
                f"depth range: expected 0 < min_depth_m < max_depth_m, got "
                f"{self.min_depth_m}, {self.max_depth_m}"
            )

    @property
    def image_size(self) -> tuple[int, int]:
        """The colour image's (width, height): what calibration and hand-eye images have."""
        return (self.color.width, self.color.height)

    @property
    def depth_size(self) -> tuple[int, int]:
        return (self.depth.width, self.depth.height)

    @property
    def X_CR(self) -> np.ndarray:
        """The rig's second camera in C, as for a stereo pair: here the depth camera (the
        planner aims the point between the two at the object; both must see it)."""
        return self.X_CD

    def eye_centres_W(self, X_WC: np.ndarray) -> np.ndarray:
        """Colour and depth camera centres (2, 3) in W, the colour camera at X_WC: a surface
        point counts as seen when both see it (the depth needs the one, the colour the other)."""
        return np.stack([X_WC[:3, 3], (X_WC @ self.X_CD)[:3, 3]])


@dataclass(frozen=True)
class DepthDesign:
    """An RGB-D device as designed (what a configuration gives). Defaults: an Intel RealSense
    D415-class camera (Intel RealSense D400 Series Product Family Datasheet: depth over 65 x 40
    deg from two imagers 55 mm apart, colour over 69 x 42 deg, depth unit 1 mm, the SDK's
    default). Depth at 848x480: its nearest depth (disparity search of 126 px: f B / 126 =
    0.29 m) lets it see the near side of the object at the scan's 0.5 m standoff, which the
    full 1280x720 (0.44 m) does not. Colour at half its 1920x1080. The colour camera sits 15 mm
    beside the depth origin (the left imager), as in the factory extrinsics of such devices."""

    depth_width_px: int = integer(848, minimum=16)
    depth_height_px: int = integer(480, minimum=16)
    depth_hfov_deg: float = positive(65.0, at_most=170.0)
    color_width_px: int = integer(960, minimum=16)
    color_height_px: int = integer(540, minimum=16)
    color_hfov_deg: float = positive(69.0, at_most=170.0)
    # Where the colour camera sits in the depth frame (the device's depth-to-colour translation).
    p_DC_m: tuple[float, float, float] = (0.015, 0.0, 0.0)
    depth_scale_m: float = positive(0.001)
    # Stereo depth baseline (for the noise model) and the range the device reports.
    baseline_m: float = positive(0.055)
    min_depth_m: float = positive(0.3)
    max_depth_m: float = positive(3.0)

    def __post_init__(self) -> None:
        check_fields("rgbd", self)

    def rgbd_camera(self) -> RgbdCamera:
        depth = _pinhole(self.depth_width_px, self.depth_height_px, self.depth_hfov_deg)
        color = _pinhole(self.color_width_px, self.color_height_px, self.color_hfov_deg)
        X_DC = np.eye(4)
        X_DC[:3, 3] = self.p_DC_m
        X_CD = np.linalg.inv(X_DC)
        return RgbdCamera(
            color,
            depth,
            X_CD,
            self.depth_scale_m,
            self.min_depth_m,
            self.max_depth_m,
            self.baseline_m,
        )


def _pinhole(width: int, height: int, hfov_deg: float) -> PinholeCamera:
    f = (width / 2) / np.tan(np.radians(hfov_deg) / 2)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    return PinholeCamera(K, np.zeros(5), width, height)


def _camera_dict(cam: PinholeCamera) -> dict:
    return {
        "image_size": [cam.width, cam.height],
        "K": cam.K.tolist(),
        "distortion": cam.distortion.tolist(),
    }


def rgbd_camera_to_dict(model: RgbdCamera) -> dict:
    return {
        "schema": SCHEMA,
        "color": _camera_dict(model.color),
        "depth": _camera_dict(model.depth),
        "X_CD": model.X_CD.tolist(),
        "depth_scale_m": float(model.depth_scale_m),
        "min_depth_m": float(model.min_depth_m),
        "max_depth_m": float(model.max_depth_m),
        "depth_baseline_m": float(model.depth_baseline_m),
        "depth_correction": float(model.depth_correction),
    }


def _require(d, key: str, where: str):
    if not isinstance(d, dict) or key not in d:
        raise CameraModelError(f"{where}: missing key '{key}'")
    return d[key]


def _camera_from(d, where: str) -> PinholeCamera:
    size = _require(d, "image_size", where)
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(n, int) for n in size)):
        raise CameraModelError(f"{where}.image_size: expected [width, height] in pixels")
    return PinholeCamera(
        _require(d, "K", where), _require(d, "distortion", where), size[0], size[1]
    )


def rgbd_camera_from_dict(d: dict, where: str = "rgbd camera") -> RgbdCamera:
    schema = _require(d, "schema", where)
    if schema != SCHEMA:
        raise CameraModelError(f"{where}: schema is '{schema}', expected '{SCHEMA}'")
    try:
        return RgbdCamera(
            _camera_from(_require(d, "color", where), f"{where}.color"),
            _camera_from(_require(d, "depth", where), f"{where}.depth"),
            np.array(_require(d, "X_CD", where), float),
            float(_require(d, "depth_scale_m", where)),
            float(_require(d, "min_depth_m", where)),
            float(_require(d, "max_depth_m", where)),
            float(d.get("depth_baseline_m", 0.0)),
            float(d.get("depth_correction", 1.0)),
        )
    except (CameraModelError, TypeError, ValueError) as e:
        raise CameraModelError(f"{where}: {e}") from None


CameraModel = StereoCamera | RgbdCamera


def camera_model_to_dict(model: CameraModel) -> dict:
    """A stereo pair's or an RGB-D device's model as a file section (its schema says which)."""
    if isinstance(model, RgbdCamera):
        return rgbd_camera_to_dict(model)
    return stereo_camera_to_dict(model)


def camera_model_from_dict(d: dict, where: str) -> CameraModel:
    if isinstance(d, dict) and d.get("schema") == SCHEMA:
        return rgbd_camera_from_dict(d, where)
    return stereo_camera_from_dict(d, where)


def save_rgbd_camera(model: RgbdCamera, path: Path) -> None:
    Path(path).write_text(yaml.safe_dump(rgbd_camera_to_dict(model), sort_keys=False))


def load_rgbd_camera(path: Path) -> RgbdCamera:
    return rgbd_camera_from_dict(read_yaml(path, "rgbd camera"), str(path))

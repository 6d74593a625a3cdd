"""What the simulator knows and the software does not: the true world and its error model.

The software side gets the nominal camera model and nominal hand-eye X_FC; the simulator renders
with the true ones, offsets the joints, and adds image noise. `truth.yaml` in a scan directory
holds this record for evaluation only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from reconstruction.common.checks import check_fields, integer, non_negative
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, rotation_about
from reconstruction.depth.camera_model import (
    RgbdCamera,
    rgbd_camera_from_dict,
    rgbd_camera_to_dict,
)
from reconstruction.stereo.camera_model import (
    StereoCamera,
    stereo_camera_from_dict,
    stereo_camera_to_dict,
)

TRUTH_SCHEMA = "scanner.truth/1"
# numpy's generators take any non-negative integer; 32 bits are plenty and print in full.
MAX_SEED = 2**32 - 1
MAX_DEPTH_SCALE_ERROR = 0.5


@dataclass(frozen=True)
class ErrorModel:
    """Seeded deviations of the true world from the nominal model (SI units).

    Defaults: hand-eye mount error of 3 mm and 1 deg (a camera bracket mounted with care);
    encoder zero offsets with a 0.01 deg standard deviation per joint, for any arm (about 0.1 mm
    at the RX60's reach); sensor noise of 2 grey levels (8-bit), typical of a CCD at good
    exposure.
    """

    seed: int = integer(0, minimum=0, maximum=MAX_SEED)
    handeye_translation_m: float = non_negative(0.003)
    handeye_rotation_rad: float = non_negative(math.radians(1.0))
    joint_offset_std_rad: float = non_negative(math.radians(0.01))
    image_noise_std: float = non_negative(2.0)
    # RGB-D sensor: the true depth is the reported depth times (1 + this) (a depth-scale error,
    # a known failure of such devices, which calibration estimates from the board). 0 by
    # default: a device within its factory calibration. Beyond +-50 % the device is broken, not
    # miscalibrated (and at -100 % every depth would be zero).
    depth_scale_error: float = 0.0
    # Who re-hangs the object between hangings (robots.simulation.operator): "instructed"
    # follows the scanner's instruction with a person's error, "random" ignores it.
    operator: str = "instructed"

    def __post_init__(self) -> None:
        if self.operator not in ("instructed", "random"):
            raise ScannerError(
                f"error_model.operator: expected 'instructed' or 'random', got {self.operator!r}"
            )
        check_fields("error_model", self)
        if not abs(self.depth_scale_error) <= MAX_DEPTH_SCALE_ERROR:
            raise ScannerError(
                f"error_model.depth_scale_error: expected a relative error within "
                f"+-{MAX_DEPTH_SCALE_ERROR:g}, got {self.depth_scale_error!r}"
            )


@dataclass(frozen=True, eq=False)
class Truth:
    """The true hand-eye pose, joint offsets (true = measured + offset), object pose and camera."""

    X_FC: np.ndarray
    joint_offsets_rad: np.ndarray
    X_WO: np.ndarray
    stereo: StereoCamera
    image_noise_std: float
    seed: int
    # The RGB-D device as it truly is (None for a stereo scan) and its depth-scale error:
    # a device reports depth / (1 + depth_scale_error).
    rgbd: RgbdCamera | None = None
    depth_scale_error: float = 0.0

    def __post_init__(self) -> None:
        for a in (self.X_FC, self.joint_offsets_rad, self.X_WO):
            a.setflags(write=False)


def _random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def sample_truth(
    error_model: ErrorModel,
    X_FC_nominal: np.ndarray,
    stereo: StereoCamera,
    X_WO: np.ndarray,
    rgbd: RgbdCamera | None = None,
    joint_count: int = 6,
) -> Truth:
    """True X_FC = nominal @ error, the error exactly of the configured size, random direction;
    one encoder offset per joint of an arm of `joint_count` joints. The offsets are the only
    error of the arm itself, so the model applies to any serial arm."""
    rng = np.random.default_rng(error_model.seed)
    R_err = rotation_about(_random_unit(rng), error_model.handeye_rotation_rad)
    X_err = make_pose(R_err, error_model.handeye_translation_m * _random_unit(rng))
    offsets = error_model.joint_offset_std_rad * rng.standard_normal(joint_count)
    return Truth(
        np.asarray(X_FC_nominal, float) @ X_err,
        offsets,
        np.array(X_WO, float),
        stereo,
        error_model.image_noise_std,
        error_model.seed,
        rgbd,
        error_model.depth_scale_error if rgbd is not None else 0.0,
    )


def truth_to_dict(truth: Truth, extra: dict | None = None) -> dict:
    d = {
        "schema": TRUTH_SCHEMA,
        "X_FC": truth.X_FC.tolist(),
        "joint_offsets_rad": truth.joint_offsets_rad.tolist(),
        "X_WO": truth.X_WO.tolist(),
        "image_noise_std": truth.image_noise_std,
        "seed": truth.seed,
        "stereo_camera": stereo_camera_to_dict(truth.stereo),
    }
    if truth.rgbd is not None:
        d["rgbd_camera"] = rgbd_camera_to_dict(truth.rgbd)
        d["depth_scale_error"] = truth.depth_scale_error
    d.update(extra or {})
    return d


def save_truth(truth: Truth, path: Path, extra: dict | None = None) -> None:
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(yaml.safe_dump(truth_to_dict(truth, extra), sort_keys=False))
    tmp.rename(path)


def load_truth(path: Path) -> tuple[Truth, dict]:
    """The truth record and the whole file (for extra keys such as the true mesh's path)."""
    try:
        d = yaml.safe_load(Path(path).read_text())
        if d.get("schema") != TRUTH_SCHEMA:
            raise ScannerError(f"{path}: schema is not {TRUTH_SCHEMA}")
        truth = Truth(
            np.array(d["X_FC"], float),
            np.array(d["joint_offsets_rad"], float),
            np.array(d["X_WO"], float),
            stereo_camera_from_dict(d["stereo_camera"], f"{path}:stereo_camera"),
            float(d["image_noise_std"]),
            int(d["seed"]),
            rgbd_camera_from_dict(d["rgbd_camera"], f"{path}:rgbd_camera")
            if "rgbd_camera" in d
            else None,
            float(d.get("depth_scale_error", 0.0)),
        )
    except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError) as e:
        raise ScannerError(f"{path}: not a readable truth file ({e})") from None
    return truth, d


def record_hung_pose(path: Path, hanging: int, X_WO: np.ndarray) -> None:
    """Write the object's true pose in pass `hanging` into the truth file (`X_WO_hangings`):
    where the operator actually hung it (only the evaluation, and a resumed simulation, read
    it)."""
    data = yaml.safe_load(Path(path).read_text())
    poses = list(data.get("X_WO_hangings", [data["X_WO"]]))
    if hanging < len(poses):
        poses[hanging] = np.asarray(X_WO, float).tolist()
    elif hanging == len(poses):
        poses.append(np.asarray(X_WO, float).tolist())
    else:
        raise ScannerError(f"{path}: hanging {hanging + 1} recorded before hanging {len(poses)}")
    data["X_WO_hangings"] = poses
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(yaml.safe_dump(data, sort_keys=False))
    tmp.rename(path)


def hung_pose_of(path: Path, hanging: int) -> np.ndarray | None:
    """The recorded true pose of pass `hanging`, None when the file holds none for it."""
    if not Path(path).is_file():
        return None
    poses = yaml.safe_load(Path(path).read_text()).get("X_WO_hangings", [])
    return np.asarray(poses[hanging], float) if hanging < len(poses) else None

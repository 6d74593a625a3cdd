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
from reconstruction.stereo.camera_model import (
    StereoCamera,
    stereo_camera_from_dict,
    stereo_camera_to_dict,
)

TRUTH_SCHEMA = "scanner.truth/1"
# numpy's generators take any non-negative integer; 32 bits are plenty and print in full.
MAX_SEED = 2**32 - 1


@dataclass(frozen=True)
class ErrorModel:
    """Seeded deviations of the true world from the nominal model (SI units).

    Defaults: hand-eye mount error of 3 mm and 1 deg (a camera bracket mounted with care);
    encoder zero offsets with a 0.01 deg standard deviation per joint (about 0.1 mm at the
    RX60's reach); sensor noise of 2 grey levels (8-bit), typical of a CCD at good exposure.
    """

    seed: int = integer(0, minimum=0, maximum=MAX_SEED)
    handeye_translation_m: float = non_negative(0.003)
    handeye_rotation_rad: float = non_negative(math.radians(1.0))
    joint_offset_std_rad: float = non_negative(math.radians(0.01))
    image_noise_std: float = non_negative(2.0)

    def __post_init__(self) -> None:
        check_fields("error_model", self)


@dataclass(frozen=True, eq=False)
class Truth:
    """The true hand-eye pose, joint offsets (true = measured + offset), object pose and camera."""

    X_FC: np.ndarray
    joint_offsets_rad: np.ndarray
    X_WO: np.ndarray
    stereo: StereoCamera
    image_noise_std: float
    seed: int

    def __post_init__(self) -> None:
        for a in (self.X_FC, self.joint_offsets_rad, self.X_WO):
            a.setflags(write=False)


def _random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def sample_truth(
    error_model: ErrorModel, X_FC_nominal: np.ndarray, stereo: StereoCamera, X_WO: np.ndarray
) -> Truth:
    """True X_FC = nominal @ error, the error exactly of the configured size, random direction."""
    rng = np.random.default_rng(error_model.seed)
    R_err = rotation_about(_random_unit(rng), error_model.handeye_rotation_rad)
    X_err = make_pose(R_err, error_model.handeye_translation_m * _random_unit(rng))
    offsets = error_model.joint_offset_std_rad * rng.standard_normal(6)
    return Truth(
        np.asarray(X_FC_nominal, float) @ X_err,
        offsets,
        np.array(X_WO, float),
        stereo,
        error_model.image_noise_std,
        error_model.seed,
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
        )
    except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError) as e:
        raise ScannerError(f"{path}: not a readable truth file ({e})") from None
    return truth, d

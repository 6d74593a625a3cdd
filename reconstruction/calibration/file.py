"""The calibration file that `scanner calibrate` writes and `scan` / `reconstruct` read.

YAML, SI units (metres, radians, pixels for intrinsics), one key per quantity:

    schema: scanner.calibration/1
    created: 2026-11-23T12:00:00+00:00
    source: simulation | offline | ...          # free text: where the data came from
    X_FC: [[...], [...], [...], [0, 0, 0, 1]]   # left optical frame C in the flange F (4x4, m)
    stereo_camera: {schema: scanner.stereo_camera/1, ...}   # or null for one camera
    camera: {image_size: [w, h], K: ..., distortion: ...}  # one camera (only when no stereo)
    X_WB: [[...]]                               # board in the robot base (information)
    board: {kind: chessboard, cols: 10, rows: 7, spacing_m: 0.02, ...}
    robot:                                      # the arm's own errors (--robot-offsets), or null
      arm: rx60                                 # the arm they belong to (absent: rx60)
      joint_offsets_rad: [d1, ..., dn]          # true joint = reported + offset, one per joint
      link_length_corrections_m: {upper_arm_m: 0.0003, ...}   # true length = drawn + this
    quality:                                    # what the calibration measured
      reprojection_rms_px: 0.12
      stereo_rms_px: 0.08                        # null for one camera
      poses_used: 18
      poses_outliers: [name, ...]
      poses_board_not_found: [name, ...]
      board_scatter_m: [sx, sy, sz]
      hand_eye_seed: park

`load_calibration` validates every field and raises ScannerError naming the file and the field.
"""

from __future__ import annotations

import datetime
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml
from reconstruction.stereo.camera_model import (
    CameraModelError,
    PinholeCamera,
    StereoCamera,
    stereo_camera_from_dict,
    stereo_camera_to_dict,
)

CALIBRATION_SCHEMA = "scanner.calibration/1"
# A robot correction beyond these is not a calibration of a working arm but a wrong model.
MAX_JOINT_OFFSET_RAD = np.radians(1.0)
MAX_LENGTH_CORRECTION_M = 0.005


@dataclass(frozen=True)
class RobotCorrection:
    """The arm's own errors a calibration found: the joints' zero offsets (rad, true = reported
    + offset, one per joint) and corrections of link lengths (m, by the arm model's keys), of
    the arm named `arm`. A scan of that arm with this calibration computes its flange poses
    from the corrected arm; a scan of another arm cannot use them."""

    joint_offsets_rad: tuple[float, ...] = (0.0,) * 6
    link_length_corrections_m: dict[str, float] = field(default_factory=dict)
    # Files written before the record named its arm hold the RX60's errors: the only arm whose
    # errors were modelled then.
    arm: str = "rx60"

    def __post_init__(self) -> None:
        offsets = tuple(float(v) for v in self.joint_offsets_rad)
        if not offsets or not all(abs(v) <= MAX_JOINT_OFFSET_RAD for v in offsets):
            raise ScannerError(
                "robot.joint_offsets_rad: expected one offset per joint within +-1 deg, got "
                f"{list(self.joint_offsets_rad)!r}"
            )
        lengths = {str(k): float(v) for k, v in dict(self.link_length_corrections_m).items()}
        if not all(abs(v) <= MAX_LENGTH_CORRECTION_M for v in lengths.values()):
            raise ScannerError(
                "robot.link_length_corrections_m: expected corrections within +-5 mm, got "
                f"{lengths!r}"
            )
        object.__setattr__(self, "joint_offsets_rad", offsets)
        object.__setattr__(self, "link_length_corrections_m", lengths)
        if not isinstance(self.arm, str) or not self.arm:
            raise ScannerError(f"robot.arm: expected the arm's name, got {self.arm!r}")

    def as_dict(self) -> dict:
        return {
            "arm": self.arm,
            "joint_offsets_rad": list(self.joint_offsets_rad),
            "link_length_corrections_m": dict(self.link_length_corrections_m),
        }


def robot_correction_from_dict(d) -> RobotCorrection | None:
    """The file's `robot:` record (None: none); errors name the field, the caller the file."""
    if d is None:
        return None
    if not isinstance(d, dict):
        raise ScannerError("robot: expected a mapping with joint_offsets_rad")
    try:
        return RobotCorrection(
            tuple(d.get("joint_offsets_rad", (0.0,) * 6)),
            dict(d.get("link_length_corrections_m") or {}),
            d.get("arm", "rx60"),
        )
    except (TypeError, ValueError) as e:
        raise ScannerError(f"robot: malformed ({e})") from None


@dataclass(frozen=True, eq=False)
class Calibration:
    """A calibrated camera rig and hand-eye pose.

    X_FC: pose of the left optical frame C in the flange F (4x4, m). stereo: the calibrated pair,
    or None when one camera was calibrated (then `camera` is that camera). X_WB: the board pose
    found in the base (information only). quality: the numbers the calibration reported.
    """

    X_FC: np.ndarray
    stereo: StereoCamera | None
    camera: PinholeCamera
    source: str = "unknown"
    created: str = ""
    X_WB: np.ndarray | None = None
    board: dict = field(default_factory=dict)
    quality: dict = field(default_factory=dict)
    # An RGB-D device's depth-scale correction (true depth = reported x this), found with the
    # board; None for a stereo rig or when not measured.
    depth_correction: float | None = None
    # The arm's own errors, when the calibration estimated and kept them (--robot-offsets).
    robot: RobotCorrection | None = None

    def __post_init__(self) -> None:
        c = self.depth_correction
        if c is not None and not (isinstance(c, int | float) and 0.5 < c < 2.0):
            raise ScannerError(f"depth_correction: expected a factor near 1, got {c!r}")
        X = np.array(self.X_FC, float)
        if X.shape != (4, 4) or not np.all(np.isfinite(X)):
            raise ScannerError("X_FC: expected a finite 4x4 matrix")
        if not np.allclose(X[3], [0, 0, 0, 1]) or not np.allclose(
            X[:3, :3] @ X[:3, :3].T, np.eye(3), atol=1e-6
        ):
            raise ScannerError("X_FC: not a rigid transform (rotation + translation)")
        X.setflags(write=False)
        object.__setattr__(self, "X_FC", X)
        if self.X_WB is not None:
            W = np.array(self.X_WB, float)
            if W.shape != (4, 4):
                raise ScannerError("X_WB: expected a 4x4 matrix")
            W.setflags(write=False)
            object.__setattr__(self, "X_WB", W)
        if self.stereo is not None and self.camera is not self.stereo.left:
            object.__setattr__(self, "camera", self.stereo.left)


def _plain(value):
    """YAML-safe plain Python values (numpy scalars/arrays -> floats/lists)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def calibration_to_dict(calibration: Calibration) -> dict:
    cam = calibration.camera
    return {
        "schema": CALIBRATION_SCHEMA,
        "created": calibration.created
        or datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "source": calibration.source,
        "X_FC": calibration.X_FC.tolist(),
        "stereo_camera": None
        if calibration.stereo is None
        else stereo_camera_to_dict(calibration.stereo),
        "camera": None
        if calibration.stereo is not None
        else {
            "image_size": [cam.width, cam.height],
            "K": cam.K.tolist(),
            "distortion": cam.distortion.tolist(),
        },
        "X_WB": None if calibration.X_WB is None else calibration.X_WB.tolist(),
        "board": _plain(calibration.board),
        "quality": _plain(calibration.quality),
        "depth_correction": calibration.depth_correction,
        "robot": None if calibration.robot is None else calibration.robot.as_dict(),
    }


def save_calibration(calibration: Calibration, path: Path) -> Path:
    """Write atomically (temporary file, then rename)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(yaml.safe_dump(calibration_to_dict(calibration), sort_keys=False))
    os.replace(tmp, path)
    return path


def _camera_from_dict(d, where: str) -> PinholeCamera:
    if not isinstance(d, dict):
        raise ScannerError(f"{where}: expected a mapping with image_size, K and distortion")
    try:
        w, h = d["image_size"]
        return PinholeCamera(d["K"], d["distortion"], int(w), int(h))
    except (KeyError, TypeError, ValueError) as e:
        raise ScannerError(f"{where}: missing or malformed field ({e})") from None
    except CameraModelError as e:
        raise ScannerError(f"{where}: {e}") from None


def calibration_from_dict(d: dict, where: str = "calibration") -> Calibration:
    if not isinstance(d, dict):
        raise ScannerError(f"{where}: not a calibration file (expected a mapping)")
    if d.get("schema") != CALIBRATION_SCHEMA:
        raise ScannerError(
            f"{where}: schema is {d.get('schema')!r}, expected {CALIBRATION_SCHEMA!r}"
        )
    if "X_FC" not in d:
        raise ScannerError(f"{where}: missing key 'X_FC'")
    stereo = None
    if d.get("stereo_camera") is not None:
        stereo = stereo_camera_from_dict(d["stereo_camera"], f"{where}:stereo_camera")
        camera = stereo.left
    else:
        camera = _camera_from_dict(d.get("camera"), f"{where}:camera")
    try:
        return Calibration(
            np.array(d["X_FC"], float),
            stereo,
            camera,
            str(d.get("source", "unknown")),
            str(d.get("created", "")),
            None if d.get("X_WB") is None else np.array(d["X_WB"], float),
            dict(d.get("board") or {}),
            dict(d.get("quality") or {}),
            d.get("depth_correction"),
            robot_correction_from_dict(d.get("robot")),
        )
    except (TypeError, ValueError) as e:
        raise ScannerError(f"{where}: malformed matrix ({e})") from None
    except ScannerError as e:
        raise ScannerError(f"{where}: {e}") from None


def load_calibration(path: Path) -> Calibration:
    """The calibration in `path` (what `--calibration FILE` reads), validated, and held to the
    limits a computed calibration is refused at (RefusedResultError, exit 3, beyond them)."""
    from reconstruction.calibration.plausibility import require_plausible

    calibration = calibration_from_dict(read_yaml(path, "calibration"), str(path))
    require_plausible(
        calibration,
        str(path),
        "a length unit read wrongly (metres for millimetres or board squares), or a "
        "hand-edited file",
    )
    return calibration


def calibrated_rgbd(model, calibration: Calibration, where: str):
    """The RGB-D device `model` as a calibration makes it: the device keeps its own depth
    camera and extrinsics and takes the calibrated colour camera and depth-scale correction.
    Images of another size than the calibration's are refused, naming `where`."""
    from dataclasses import replace

    color = calibration.camera
    if (color.width, color.height) != model.image_size:
        raise ScannerError(
            f"{where}: calibrated for {color.width}x{color.height} images, the colour "
            f"camera delivers {model.image_size[0]}x{model.image_size[1]}"
        )
    correction = calibration.depth_correction or 1.0
    return replace(model, color=color, depth_correction=correction)


def calibrated_stereo(model: StereoCamera, calibration: Calibration, where: str) -> StereoCamera:
    """The calibration's stereo pair for the nominal pair `model`; a calibration without one,
    or of another image size, is refused naming `where`."""
    if calibration.stereo is None:
        raise ScannerError(f"{where}: holds no stereo camera model")
    if calibration.stereo.image_size != model.image_size:
        raise ScannerError(
            f"{where}: calibrated for {calibration.stereo.image_size} images, the camera "
            f"delivers {model.image_size}"
        )
    return calibration.stereo

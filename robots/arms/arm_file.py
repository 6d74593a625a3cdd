"""The arm file: one YAML file that makes a robot arm known to the scanner.

    name: ur5e
    model: ../../../robots/arms/models/ur5e/ur_description/urdf/ur5e.xacro   # URDF, SDF or xacro
    packages: {ur_description: ../../../robots/arms/models/ur5e/ur_description}
    flange_link: tool0                       # the link whose frame is the flange F
    base_pose: {xyz_m: [0, 0, 0], rpy_rad: [0, 0, 0]}        # X_WB of the model's root link
    joint_limits:                            # only what the model lacks
      shoulder_pan_joint: {acceleration_rad_s2: 6.0}
    accuracy_m: 0.0005
    repeatability_m: 0.00003
    ik: {redundant_joint: iiwa_joint_3, redundant_steps: 9, seeds: 24}    # optional
    home_q_rad: [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]   # optional: where a scan starts

Paths are relative to the arm file. Every error is one line naming the file and the field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml


@dataclass(frozen=True)
class IkSettings:
    """seeds: starts per solve (per grid value on a redundant arm). redundant_joint: the joint
    fixed on a grid when the arm has more than 6 joints (None: the third). redundant_steps: grid
    values over its range, ends included. Tolerances: what a solution must reach (m, rad), and
    below what joint difference (rad or m) two answers are one solution. turn_variants: add the
    2 pi-shifted copies of wide revolute joints."""

    seeds: int = 48
    redundant_joint: str | None = None
    redundant_steps: int = 9
    position_tolerance_m: float = 1e-9
    orientation_tolerance_rad: float = 1e-9
    distinct_tolerance: float = 1e-6
    turn_variants: bool = True

    def replace(self, **changes) -> IkSettings:
        return replace(self, **changes)


MODEL_SUFFIXES = (".urdf", ".sdf", ".xacro")


@dataclass(frozen=True)
class JointLimitFill:
    """Limits of one joint for what its model lacks (rad, rad/s, rad/s^2); None: not given."""

    lower_rad: float | None = None
    upper_rad: float | None = None
    velocity_rad_s: float | None = None
    acceleration_rad_s2: float | None = None


@dataclass(frozen=True)
class ArmFile:
    """A validated arm file; paths absolute. `base_xyz_m`, `base_rpy_rad`: X_WB, the model's root
    link in the world (roll-pitch-yaw about fixed x, y, z, as in URDF)."""

    path: Path
    name: str
    model: Path
    packages: tuple[tuple[str, Path], ...]
    flange_link: str
    base_xyz_m: tuple[float, float, float]
    base_rpy_rad: tuple[float, float, float]
    accuracy_m: float
    repeatability_m: float
    joint_limits: tuple[tuple[str, JointLimitFill], ...] = ()
    ik: IkSettings = field(default_factory=IkSettings)
    home_q_rad: tuple[float, ...] | None = None

    def limit_fill(self, joint: str) -> JointLimitFill:
        return dict(self.joint_limits).get(joint, JointLimitFill())


_REQUIRED = ("name", "model", "flange_link", "base_pose", "accuracy_m", "repeatability_m")
_OPTIONAL = ("packages", "joint_limits", "ik", "home_q_rad")


def _fail(path: Path, key: str, expected: str, value: object = None) -> ScannerError:
    got = "" if value is None else f", got {value!r}"
    return ScannerError(f"{path}: {key}: expected {expected}{got}")


def _string(path: Path, key: str, value: object) -> str:
    if not isinstance(value, str) or not value:
        raise _fail(path, key, "a non-empty string", value)
    return value


def _number(path: Path, key: str, value: object, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _fail(path, key, "a finite number", value)
    if positive and value <= 0:
        raise _fail(path, key, "a number > 0", value)
    return float(value)


def _vector3(path: Path, key: str, value: object) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise _fail(path, key, "a list of 3 numbers", value)
    x, y, z = (_number(path, f"{key}[{i}]", v) for i, v in enumerate(value))
    return x, y, z


def _mapping(path: Path, key: str, value: object, allowed: tuple[str, ...]) -> dict:
    if not isinstance(value, dict):
        raise _fail(path, key, "a mapping", value)
    unknown = sorted(str(k) for k in value if k not in allowed)
    if unknown:
        prefix = f"{key}." if key else ""
        raise ScannerError(
            f"{path}: {prefix}{unknown[0]}: unknown key (valid keys: {', '.join(allowed)})"
        )
    return value


def _existing(path: Path, key: str, value: object, folder: bool) -> Path:
    target = (path.parent / _string(path, key, value)).resolve()
    kind = "folder" if folder else "file"
    if not (target.is_dir() if folder else target.is_file()):
        raise ScannerError(f"{path}: {key}: expected an existing {kind}, {target} does not exist")
    return target


def _joint_limits(path: Path, value: object) -> tuple[tuple[str, JointLimitFill], ...]:
    names = tuple(f.name for f in fields(JointLimitFill))
    out = []
    for joint, limits in _mapping(path, "joint_limits", value, tuple(value or ())).items():
        key = f"joint_limits.{joint}"
        given = _mapping(path, key, limits, names)
        speeds = ("velocity_rad_s", "acceleration_rad_s2")
        out.append(
            (
                str(joint),
                JointLimitFill(
                    **{k: _number(path, f"{key}.{k}", v, k in speeds) for k, v in given.items()}
                ),
            )
        )
    return tuple(out)


def _ik(path: Path, value: object) -> IkSettings:
    given = _mapping(path, "ik", value, ("redundant_joint", "redundant_steps", "seeds"))
    settings = IkSettings()
    if "redundant_joint" in given:
        settings = settings.replace(
            redundant_joint=_string(path, "ik.redundant_joint", given["redundant_joint"])
        )
    for key in ("redundant_steps", "seeds"):
        if key in given:
            v = given[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise _fail(path, f"ik.{key}", "an integer >= 1", v)
            settings = settings.replace(**{key: v})
    return settings


def _joint_vector(path: Path, key: str, value: object) -> tuple[float, ...]:
    if not isinstance(value, list) or not value:
        raise _fail(path, key, "a list of joint positions (rad, or m for a prismatic joint)", value)
    return tuple(_number(path, f"{key}[{i}]", v) for i, v in enumerate(value))


def read_arm_file(path: Path | str) -> ArmFile:
    """The arm file's own checks (syntax, fields, paths); `load_arm_file` adds the model's."""
    path = Path(path).resolve()
    data = read_yaml(path, "arm file")
    if data is None:
        data = {}
    data = _mapping(path, "", data, _REQUIRED + _OPTIONAL)
    for key in _REQUIRED:
        if key not in data:
            raise ScannerError(f"{path}: {key}: missing (required fields: {', '.join(_REQUIRED)})")
    model = _existing(path, "model", data["model"], folder=False)
    if not model.name.endswith(MODEL_SUFFIXES):
        raise _fail(path, "model", f"a file ending in {', '.join(MODEL_SUFFIXES)}", model.name)
    packages = tuple(
        (str(name), _existing(path, f"packages.{name}", folder_, folder=True))
        for name, folder_ in _mapping(
            path, "packages", data.get("packages") or {}, tuple(data.get("packages") or ())
        ).items()
    )
    base = _mapping(path, "base_pose", data["base_pose"], ("xyz_m", "rpy_rad"))
    for key in ("xyz_m", "rpy_rad"):
        if key not in base:
            raise ScannerError(f"{path}: base_pose.{key}: missing (expected a list of 3 numbers)")
    return ArmFile(
        path=path,
        name=_string(path, "name", data["name"]),
        model=model,
        packages=packages,
        flange_link=_string(path, "flange_link", data["flange_link"]),
        base_xyz_m=_vector3(path, "base_pose.xyz_m", base["xyz_m"]),
        base_rpy_rad=_vector3(path, "base_pose.rpy_rad", base["rpy_rad"]),
        accuracy_m=_number(path, "accuracy_m", data["accuracy_m"], positive=True),
        repeatability_m=_number(path, "repeatability_m", data["repeatability_m"], positive=True),
        joint_limits=_joint_limits(path, data.get("joint_limits") or {}),
        ik=_ik(path, data.get("ik") or {}),
        home_q_rad=None
        if data.get("home_q_rad") is None
        else _joint_vector(path, "home_q_rad", data["home_q_rad"]),
    )

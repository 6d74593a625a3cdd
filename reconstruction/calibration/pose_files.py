"""Robot pose files written by other systems: named layouts and conventions -> X_WF (SI units).

A pose is the flange (tool) frame F in the robot base W. Layouts (`POSE_LAYOUTS`, numbers in
this order):
- "matrix":      a 4x4 (16 numbers) or 3x4 (12 numbers) homogeneous matrix, row by row;
- "xyz_euler":   x y z a b c (Euler angles a, b, c in the sequence `euler`);
- "euler_xyz":   a b c x y z (angles first, e.g. the Open3DV data set: Rx Ry Rz X Y Z);
- "xyz_quat":    x y z qx qy qz qw;
- "xyz_wxyz":    x y z qw qx qy qz (ABB robtarget order);
- "xyz_rotvec":  x y z rx ry rz (axis * angle, e.g. Universal Robots).

`euler` uses scipy's sequence names: lowercase = extrinsic (fixed axes), uppercase = intrinsic
(moving axes). "xyz" (extrinsic) means R = Rz(c) @ Ry(b) @ Rx(a), the same rotation as "ZYX"
intrinsic with the angles reversed; the Open3DV (Yaskawa) data use "xyz". Lengths "m" or "mm";
angles "deg" or "rad". `inverse=True` reads files that hold the base in the flange (X_FW).

Presets (`POSE_PRESETS`) name common controller conventions; check any of them against the
board-in-base scatter that the calibration report prints (a wrong convention gives tens of mm).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert as inverse_pose
from reconstruction.common.transforms import make_pose

POSE_LAYOUTS: dict[str, tuple[int, ...]] = {
    "matrix": (16, 12),
    "xyz_euler": (6,),
    "euler_xyz": (6,),
    "xyz_quat": (7,),
    "xyz_wxyz": (7,),
    "xyz_rotvec": (6,),
}
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
ANGLE_UNITS = {"rad": 1.0, "deg": np.pi / 180.0}
_EULER = re.compile(r"^([xyz]{3}|[XYZ]{3})$")


@dataclass(frozen=True)
class PoseFormat:
    layout: str = "matrix"
    euler: str = "xyz"
    length_unit: str = "m"
    angle_unit: str = "deg"
    inverse: bool = False

    def __post_init__(self) -> None:
        if self.layout not in POSE_LAYOUTS:
            raise ScannerError(
                f"unknown pose layout '{self.layout}'; valid: {', '.join(POSE_LAYOUTS)}"
            )
        if not _EULER.match(self.euler) or any(
            self.euler[i] == self.euler[i + 1] for i in range(2)
        ):
            raise ScannerError(
                f"unknown Euler convention '{self.euler}'; use three axes from x, y, z with no "
                "axis twice in a row, lowercase for extrinsic (fixed) or uppercase for intrinsic "
                "(moving) axes, e.g. xyz, ZYX, XYZ, zyz"
            )
        if self.length_unit not in LENGTH_UNITS:
            raise ScannerError(
                f"unknown length unit '{self.length_unit}'; valid: {', '.join(LENGTH_UNITS)}"
            )
        if self.angle_unit not in ANGLE_UNITS:
            raise ScannerError(
                f"unknown angle unit '{self.angle_unit}'; valid: {', '.join(ANGLE_UNITS)}"
            )

    @property
    def counts(self) -> tuple[int, ...]:
        return POSE_LAYOUTS[self.layout]


POSE_PRESETS: dict[str, PoseFormat] = {
    # Open3DV EyeInHand data (Yaskawa): Rx Ry Rz [deg] X Y Z [mm], R = Rz Ry Rx.
    "open3dv": PoseFormat("euler_xyz", "xyz", "mm", "deg"),
    # Yaskawa / Fanuc: X Y Z Rx Ry Rz (W P R), fixed-axis x-y-z, mm and degrees.
    "yaskawa": PoseFormat("xyz_euler", "xyz", "mm", "deg"),
    "fanuc": PoseFormat("xyz_euler", "xyz", "mm", "deg"),
    # KUKA: X Y Z A B C, R = Rz(A) Ry(B) Rx(C), i.e. intrinsic Z-Y-X, mm and degrees.
    "kuka": PoseFormat("xyz_euler", "ZYX", "mm", "deg"),
    # Staubli VAL3 trsf: x y z rx ry rz, R = Rx Ry Rz (intrinsic X-Y-Z), mm and degrees.
    "staubli": PoseFormat("xyz_euler", "XYZ", "mm", "deg"),
    # ABB robtarget: x y z q1 q2 q3 q4 (q1 = w), mm.
    "abb": PoseFormat("xyz_wxyz", "xyz", "mm", "deg"),
    # Universal Robots: x y z rx ry rz (rotation vector), m and rad.
    "ur": PoseFormat("xyz_rotvec", "xyz", "m", "rad"),
    "matrix_m": PoseFormat("matrix", "xyz", "m", "rad"),
    "matrix_mm": PoseFormat("matrix", "xyz", "mm", "rad"),
}


def pose_format(preset: str | None = None, **overrides) -> PoseFormat:
    """A preset by name (or the default) with field overrides (None values are ignored)."""
    if preset is None:
        base = PoseFormat()
    elif preset in POSE_PRESETS:
        base = POSE_PRESETS[preset]
    else:
        raise ScannerError(f"unknown pose convention '{preset}'; valid: {', '.join(POSE_PRESETS)}")
    changes = {k: v for k, v in overrides.items() if v is not None}
    return replace(base, **changes) if changes else base


def pose_from_numbers(values: np.ndarray, fmt: PoseFormat, where: str) -> np.ndarray:
    """X_WF (4x4, metres) from one pose's numbers."""
    v = np.asarray(values, float)
    if len(v) not in fmt.counts:
        expected = " or ".join(str(c) for c in fmt.counts)
        raise ScannerError(
            f"{where}: found {len(v)} numbers, the pose layout '{fmt.layout}' needs {expected}"
        )
    if not np.all(np.isfinite(v)):
        raise ScannerError(f"{where}: pose values must be finite numbers")
    scale = LENGTH_UNITS[fmt.length_unit]
    angle = ANGLE_UNITS[fmt.angle_unit]
    if fmt.layout == "matrix":
        X = np.vstack([v.reshape(-1, 4), [0, 0, 0, 1]]) if len(v) == 12 else v.reshape(4, 4)
        if not np.allclose(X[3], [0, 0, 0, 1], atol=1e-9):
            raise ScannerError(f"{where}: the last matrix row must be 0 0 0 1, got {X[3]}")
        R = X[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
            raise ScannerError(f"{where}: the upper-left 3x3 block is not a rotation matrix")
        # Re-orthonormalise: printed matrices carry 4-6 digits.
        U, _, Vt = np.linalg.svd(R)
        X = make_pose(U @ Vt, X[:3, 3] * scale)
    elif fmt.layout in ("xyz_euler", "euler_xyz"):
        xyz, abc = (v[:3], v[3:]) if fmt.layout == "xyz_euler" else (v[3:], v[:3])
        X = make_pose(Rotation.from_euler(fmt.euler, abc * angle).as_matrix(), xyz * scale)
    elif fmt.layout in ("xyz_quat", "xyz_wxyz"):
        q = v[3:] if fmt.layout == "xyz_quat" else np.r_[v[4:], v[3]]
        norm = np.linalg.norm(q)
        if not 0.99 < norm < 1.01:
            raise ScannerError(f"{where}: quaternion norm is {norm:.4f}, expected 1")
        X = make_pose(Rotation.from_quat(q / norm).as_matrix(), v[:3] * scale)
    else:  # xyz_rotvec
        X = make_pose(Rotation.from_rotvec(v[3:] * angle).as_matrix(), v[:3] * scale)
    return inverse_pose(X) if fmt.inverse else X


_SEPARATORS = re.compile(r"[\s,;]+")


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _numbers(text: str, where: str) -> list[tuple[int, list[float]]]:
    """(line number, numbers) of every line holding numbers.

    Written by hand or exported from a spreadsheet: '#' starts a comment (a whole line or the end
    of one), blank lines are skipped, numbers are separated by spaces, tabs, commas or
    semicolons and may be quoted ("1.5"), and the first line is skipped as a CSV header when it has
    letters and no number ("x,y,z,rx,ry,rz"). Decimal commas are not supported (a comma
    separates numbers)."""
    rows: list[tuple[int, list[float]]] = []
    first = True
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        tokens = [t.strip("\"'") for t in _SEPARATORS.split(line) if t]
        header = first and any(c.isalpha() for c in line) and not any(map(_is_number, tokens))
        first = False
        if header:
            continue
        try:
            rows.append((n, [float(t) for t in tokens]))
        except ValueError:
            raise ScannerError(f"{where} line {n}: not a list of numbers: '{line}'") from None
    return rows


def _read_text(path: Path) -> str:
    """The file's text; a UTF-8 byte order mark (spreadsheets on Windows write one) is dropped,
    and Windows or old Mac line endings read as plain ones."""
    try:
        return path.read_text(encoding="utf-8-sig")
    except OSError as e:
        raise ScannerError(f"{path}: cannot read pose file ({e.strerror})") from None
    except UnicodeDecodeError:
        raise ScannerError(f"{path}: not UTF-8 text; save it as plain text (UTF-8)") from None


def read_pose_file(path: Path, fmt: PoseFormat) -> np.ndarray:
    """One pose in a file (numbers on one or several lines, e.g. 6 lines of one number)."""
    path = Path(path)
    values = [x for _, row in _numbers(_read_text(path), str(path)) for x in row]
    return pose_from_numbers(np.array(values), fmt, str(path))


def read_pose_list(path: Path, fmt: PoseFormat) -> list[np.ndarray]:
    """Many poses, one per line (each line has the layout's column count)."""
    path = Path(path)
    poses = []
    for n, row in _numbers(_read_text(path), str(path)):
        if len(row) not in fmt.counts:
            expected = " or ".join(str(c) for c in fmt.counts)
            raise ScannerError(
                f"{path} line {n}: {len(row)} columns, the pose layout '{fmt.layout}' needs "
                f"{expected} (one pose per line)"
            )
        poses.append(pose_from_numbers(np.array(row), fmt, f"{path} line {n}"))
    return poses

"""The hand-eye transform X_FC as a ROS static transform (hand_eye_tf.yaml and the
static_transform_publisher commands), and hand-eye files easy_handeye writes (the layout is
described in `reconstruction.calibration.exchange`)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import check_pose, make_pose
from reconstruction.common.yaml_files import read_yaml

HAND_EYE_TF = "hand_eye_tf.yaml"
# ROS names: a letter first, then letters, digits and underscores, '/' between name parts; tf2
# refuses frame ids that start with '/'.
ROS_FRAME_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*")
# Files print quaternions rounded (four decimals leave the length off by 1e-4 at most); further
# off than this, the four numbers are not a rotation.
QUATERNION_NORM_TOLERANCE = 1e-3


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

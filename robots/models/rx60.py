"""Staubli RX60 kinematic data and its URDF.

Source: Staubli RX60 datasheet values (shoulder height 0.341 m, upper arm 0.290 m, forearm
0.310 m, wrist centre to flange 0.065 m, J2/J3 lateral offset 0.049 m, joint ranges and nominal
maximum speeds). The lateral offset IS modelled: the elbow axis J3 is
shifted by +0.049 m along the J2 axis (y of link 2), as on the real arm.

Zero configuration: the arm points straight up, every joint axis of J2/J3/J5 along +y, J1/J4/J6
along +z. The flange frame F (tool0) sits 0.065 m beyond the wrist centre with +z out of the
flange face.

Acceleration limits are not in the datasheet; we assume each joint reaches its maximum speed in
0.3 s (a typical value for a lightly loaded arm of this class) and say so in the README.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

_DEG = math.pi / 180.0
ACCELERATION_TIME_S = 0.3


# The RX60's link lengths a kinematic calibration may correct, and their words.
LINK_LENGTHS = {
    "shoulder_height_m": "shoulder height",
    "upper_arm_m": "upper arm length",
    "elbow_offset_m": "elbow offset",
    "forearm_m": "forearm length",
    "wrist_to_flange_m": "wrist-to-flange length",
}


@dataclass(frozen=True)
class RX60:
    """Kinematic parameters (metres) and joint limits (radians, rad/s, rad/s^2)."""

    shoulder_height_m: float = 0.341
    upper_arm_m: float = 0.290
    elbow_offset_m: float = 0.049
    forearm_m: float = 0.310
    wrist_to_flange_m: float = 0.065
    lower_limits_rad: tuple[float, ...] = tuple(
        v * _DEG for v in (-160.0, -127.5, -134.5, -270.0, -109.5, -270.0)
    )
    upper_limits_rad: tuple[float, ...] = tuple(
        v * _DEG for v in (160.0, 127.5, 134.5, 270.0, 120.5, 270.0)
    )
    velocity_limits_rad_s: tuple[float, ...] = tuple(
        v * _DEG for v in (287.0, 287.0, 319.0, 410.0, 320.0, 700.0)
    )
    joint_names: tuple[str, ...] = field(
        default=("joint1", "joint2", "joint3", "joint4", "joint5", "joint6")
    )

    @property
    def acceleration_limits_rad_s2(self) -> tuple[float, ...]:
        return tuple(v / ACCELERATION_TIME_S for v in self.velocity_limits_rad_s)

    @property
    def lower(self) -> np.ndarray:
        return np.array(self.lower_limits_rad)

    @property
    def upper(self) -> np.ndarray:
        return np.array(self.upper_limits_rad)

    def with_length_corrections(self, corrections_m) -> RX60:
        """This arm with its links longer by `corrections_m` ({field name: metres}, fields of
        LINK_LENGTHS): the arm a kinematic calibration found."""
        from dataclasses import replace

        unknown = set(corrections_m) - set(LINK_LENGTHS)
        if unknown:
            raise ValueError(f"not link lengths of the RX60: {', '.join(sorted(unknown))}")
        return replace(self, **{k: getattr(self, k) + float(v) for k, v in corrections_m.items()})

    def within_limits(self, q: np.ndarray, tol_rad: float = 1e-9) -> bool:
        q = np.asarray(q, dtype=float)
        return bool(
            np.all(np.isfinite(q))
            and np.all(q >= self.lower - tol_rad)
            and np.all(q <= self.upper + tol_rad)
        )


ROBOT_MODEL_NAME = "rx60"
FLANGE_FRAME = "tool0"
_ORANGE = "0.95 0.55 0.1 1"
_GREY = "0.3 0.3 0.32 1"
# Collision primitives enclose the visual ones by this much on every side.
_COLLISION_MARGIN_M = 0.005


def _cylinder(name: str, xyz, rpy, radius: float, length: float, rgba: str) -> str:
    m = _COLLISION_MARGIN_M
    origin = f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/>'
    return f"""
    <visual name="{name}_visual">{origin}
      <geometry><cylinder radius="{radius}" length="{length}"/></geometry>
      <material name="{name}_material"><color rgba="{rgba}"/></material>
    </visual>
    <collision name="{name}_collision">{origin}
      <geometry><cylinder radius="{radius + m}" length="{length + 2 * m}"/></geometry>
    </collision>"""


def _sphere(name: str, xyz, radius: float, rgba: str) -> str:
    origin = f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}"/>'
    return f"""
    <visual name="{name}_visual">{origin}
      <geometry><sphere radius="{radius}"/></geometry>
      <material name="{name}_material"><color rgba="{rgba}"/></material>
    </visual>
    <collision name="{name}_collision">{origin}
      <geometry><sphere radius="{radius + _COLLISION_MARGIN_M}"/></geometry>
    </collision>"""


def _inertial(mass: float, com_z: float) -> str:
    i = 0.01 * mass
    return f"""
    <inertial><origin xyz="0 0 {com_z}"/><mass value="{mass}"/>
      <inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="{i}"/></inertial>"""


def _link(name: str, body: str, mass: float = 1.0, com_z: float = 0.0) -> str:
    return f'  <link name="{name}">{_inertial(mass, com_z)}{body}\n  </link>\n'


def _joint(name: str, parent: str, child: str, xyz, axis, lo, hi, vel) -> str:
    return f"""  <joint name="{name}" type="revolute">
    <parent link="{parent}"/><child link="{child}"/>
    <origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}"/><axis xyz="{axis[0]} {axis[1]} {axis[2]}"/>
    <limit lower="{lo!r}" upper="{hi!r}" velocity="{vel!r}" effort="100"/>
  </joint>
"""


def rx60_urdf(robot: RX60 = RX60()) -> str:
    """URDF text of the arm (base_link .. tool0) with visual and enclosing collision primitives."""
    h, a2, d3, a3 = (
        robot.shoulder_height_m,
        robot.upper_arm_m,
        robot.elbow_offset_m,
        robot.forearm_m,
    )
    half_pi = math.pi / 2
    lo, hi, vel = robot.lower_limits_rad, robot.upper_limits_rad, robot.velocity_limits_rad_s
    links = [
        _link("base_link", _cylinder("base", (0, 0, 0.09), (0, 0, 0), 0.1, 0.18, _GREY), 10.0),
        _link(
            "link1",
            _cylinder("column", (0, 0, 0.25), (0, 0, 0), 0.08, 0.14, _ORANGE)
            + _cylinder("shoulder", (0, 0, h), (half_pi, 0, 0), 0.08, 0.16, _ORANGE),
            8.0,
            0.25,
        ),
        _link(
            "link2",
            _cylinder("upper_arm", (0, -0.07, a2 / 2), (0, 0, 0), 0.055, a2, _ORANGE)
            + _cylinder("elbow2", (0, -0.04, a2), (half_pi, 0, 0), 0.06, 0.08, _ORANGE),
            6.0,
            a2 / 2,
        ),
        _link(
            "link3",
            _cylinder("elbow3", (0, 0.0, 0), (half_pi, 0, 0), 0.06, 0.09, _ORANGE)
            + _cylinder("forearm", (0, 0, 0.13), (0, 0, 0), 0.045, 0.18, _ORANGE),
            4.0,
            0.12,
        ),
        _link("link4", _cylinder("wrist4", (0, 0, -0.075), (0, 0, 0), 0.04, 0.04, _ORANGE), 1.0),
        _link("link5", _sphere("wrist5", (0, 0, 0), 0.042, _ORANGE), 0.8),
        _link(
            "link6",
            _cylinder(
                "flange", (0, 0, robot.wrist_to_flange_m - 0.01), (0, 0, 0), 0.03, 0.02, _GREY
            ),
            0.2,
        ),
        f'  <link name="{FLANGE_FRAME}"/>\n',
    ]
    joints = [
        _joint("joint1", "base_link", "link1", (0, 0, 0), (0, 0, 1), lo[0], hi[0], vel[0]),
        _joint("joint2", "link1", "link2", (0, 0, h), (0, 1, 0), lo[1], hi[1], vel[1]),
        _joint("joint3", "link2", "link3", (0, d3, a2), (0, 1, 0), lo[2], hi[2], vel[2]),
        _joint("joint4", "link3", "link4", (0, 0, a3), (0, 0, 1), lo[3], hi[3], vel[3]),
        _joint("joint5", "link4", "link5", (0, 0, 0), (0, 1, 0), lo[4], hi[4], vel[4]),
        _joint("joint6", "link5", "link6", (0, 0, 0), (0, 0, 1), lo[5], hi[5], vel[5]),
        f"""  <joint name="flange" type="fixed">
    <parent link="link6"/><child link="{FLANGE_FRAME}"/>
    <origin xyz="0 0 {robot.wrist_to_flange_m}"/>
  </joint>
""",
    ]
    return (
        f'<?xml version="1.0"?>\n<robot name="{ROBOT_MODEL_NAME}">\n'
        + "".join(links)
        + "".join(joints)
        + "</robot>\n"
    )

"""The Staubli RX60 as an `Arm`: its kinematic data, its URDF, its closed-form kinematics.

Source: Staubli RX60 datasheet values (shoulder height 0.341 m, upper arm 0.290 m, forearm
0.310 m, wrist centre to flange 0.065 m, J2/J3 lateral offset 0.049 m, joint ranges and nominal
maximum speeds). The lateral offset IS modelled: the elbow axis J3 is
shifted by +0.049 m along the J2 axis (y of link 2), as on the real arm.

Zero configuration: the arm points straight up, every joint axis of J2/J3/J5 along +y, J1/J4/J6
along +z. The flange frame F (tool0) sits 0.065 m beyond the wrist centre with +z out of the
flange face.

Acceleration limits are not in the datasheet; we assume each joint reaches its maximum speed in
0.3 s (a typical value for a lightly loaded arm of this class) and say so in the README.

Inverse kinematics in closed form over all branches: the RX60 has a spherical wrist, so the
wrist centre p_WW = p_WF - L6 z_F fixes q1..q3 (shoulder left/right x elbow up/down: up to 4
branches) and the wrist orientation R_36 = Rz(q4) Ry(q5) Rz(q6) fixes q4..q6 (wrist flip: 2
branches). J4 and J6 range over +-270 deg, so each branch also appears shifted by +-2 pi where the
limits allow. Every solution is verified by the same closed-form forward kinematics before it is
returned.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from reconstruction.calibration.joint_chain import JointChain
from reconstruction.calibration.robot_errors import ArmModel
from robots.arms.limits import within_limits

# Drake is imported only where the arm's model is made: the controller emulator and the command
# line's parser read the RX60's numbers and must not wait for it.
if TYPE_CHECKING:
    from pydrake.multibody.plant import MultibodyPlant

    from robots.arms.arm import Arm

_DEG = math.pi / 180.0
ACCELERATION_TIME_S = 0.3
# Stäubli RX60 datasheet: repeatability +-0.02 mm. Stäubli publishes no absolute accuracy; 0.5 mm
# is the uncalibrated accuracy this product assumes.
REPEATABILITY_M = 0.00002
ACCURACY_M = 0.0005
TWO_PI = 2 * math.pi
# Folded: elbow up, camera looking forward and down at the table, well below the object.
HOME_Q = (0.0, -0.4, 2.3, 0.0, 0.8, 0.0)
# Below this sin(q5) the wrist is singular: q4 + q6 is fixed, q4 is taken from the seed.
WRIST_SINGULAR_EPS = 1e-9


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
        return within_limits(q, self.lower, self.upper, tol_rad)


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


# --- closed-form kinematics --------------------------------------------------------------------


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def fk_flange(robot: RX60, q: np.ndarray) -> np.ndarray:
    """Closed-form X_WF(q) (4x4), the same chain as the URDF."""
    q1, q2, q3, q4, q5, q6 = q
    h, a2, d, a3 = robot.shoulder_height_m, robot.upper_arm_m, robot.elbow_offset_m, robot.forearm_m
    R1 = _rz(q1)
    x = a2 * math.sin(q2) + a3 * math.sin(q2 + q3)
    z = h + a2 * math.cos(q2) + a3 * math.cos(q2 + q3)
    p_WW = R1 @ np.array([x, d, z])
    R_WF = R1 @ _ry(q2 + q3) @ _rz(q4) @ _ry(q5) @ _rz(q6)
    X = np.eye(4)
    X[:3, :3] = R_WF
    X[:3, 3] = p_WW + robot.wrist_to_flange_m * R_WF[:, 2]
    return X


def arm_model(robot: RX60 = RX60()) -> ArmModel:
    """The RX60's kinematics with error parameters (joint zero offsets, then LINK_LENGTHS'
    corrections) for the hand-eye calibration's robot errors."""
    fields = tuple(LINK_LENGTHS)

    def flange_pose(q: np.ndarray, p: np.ndarray) -> np.ndarray:
        arm = robot.with_length_corrections(dict(zip(fields, p[6:]))) if np.any(p[6:]) else robot
        return fk_flange(arm, np.asarray(q, float) + p[:6])

    return ArmModel(
        flange_pose, fields, tuple(LINK_LENGTHS.values()), ROBOT_MODEL_NAME, len(robot.joint_names)
    )


def rx60_chain(robot: RX60 = RX60()) -> JointChain:
    """The chain of rx60_urdf in numbers: every joint frame parallel to the base's, J2/J3/J5
    about +y, J1/J4/J6 about +z."""
    h, a2, d3, a3 = (
        robot.shoulder_height_m,
        robot.upper_arm_m,
        robot.elbow_offset_m,
        robot.forearm_m,
    )
    origins = [(0, 0, 0), (0, 0, h), (0, d3, a2), (0, 0, a3), (0, 0, 0), (0, 0, 0)]
    origins.append((0, 0, robot.wrist_to_flange_m))
    X_MF = np.repeat(np.eye(4)[None], len(origins), axis=0)
    X_MF[:, :3, 3] = origins
    y, z = (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    axes = [z, y, y, z, y, z]
    return JointChain(ROBOT_MODEL_NAME, robot.joint_names, FLANGE_FRAME, X_MF, axes, [True] * 6)


def _arm_branches(robot: RX60, p_WW: np.ndarray) -> list[tuple[float, float, float]]:
    """(q1, q2, q3) placing the wrist centre at p_WW: up to four branches."""
    h, a2, d, a3 = robot.shoulder_height_m, robot.upper_arm_m, robot.elbow_offset_m, robot.forearm_m
    px, py, pz = p_WW
    r2 = px * px + py * py - d * d
    if r2 < 0:
        return []
    out = []
    for x in {math.sqrt(r2), -math.sqrt(r2)}:
        q1 = math.atan2(py, px) - math.atan2(d, x)
        z = pz - h
        c3 = (x * x + z * z - a2 * a2 - a3 * a3) / (2 * a2 * a3)
        if abs(c3) > 1:
            continue
        for q3 in {math.acos(c3), -math.acos(c3)}:
            q2 = math.atan2(x, z) - math.atan2(a3 * math.sin(q3), a2 + a3 * math.cos(q3))
            out.append((_wrap(q1), _wrap(q2), q3))
    return out


def _wrap(a: float) -> float:
    return (a + math.pi) % TWO_PI - math.pi


def _wrist_branches(R_36: np.ndarray, q4_seed: float) -> list[tuple[float, float, float]]:
    s5 = math.hypot(R_36[0, 2], R_36[1, 2])
    q5 = math.atan2(s5, R_36[2, 2])
    if s5 < WRIST_SINGULAR_EPS:
        q46 = math.atan2(R_36[1, 0], R_36[0, 0])
        return [(q4_seed, q5, _wrap(q46 - q4_seed))]
    q4 = math.atan2(R_36[1, 2], R_36[0, 2])
    q6 = math.atan2(R_36[2, 1], -R_36[2, 0])
    return [(q4, q5, q6), (_wrap(q4 + math.pi), -q5, _wrap(q6 + math.pi))]


def ik_flange(
    robot: RX60, X_WF: np.ndarray, q_seed: np.ndarray | None = None, tol_m: float = 1e-7
) -> list[np.ndarray]:
    """All joint solutions within limits that put the flange at X_WF (verified by FK)."""
    q_seed = np.zeros(6) if q_seed is None else np.asarray(q_seed, float)
    R_WF, p_WF = X_WF[:3, :3], X_WF[:3, 3]
    p_WW = p_WF - robot.wrist_to_flange_m * R_WF[:, 2]
    lo, hi = robot.lower, robot.upper
    solutions = []
    for q1, q2, q3 in _arm_branches(robot, p_WW):
        R_36 = (_rz(q1) @ _ry(q2 + q3)).T @ R_WF
        for q4, q5, q6 in _wrist_branches(R_36, q_seed[3]):
            for k4, k6 in itertools.product((-1, 0, 1), repeat=2):
                q = np.array([q1, q2, q3, q4 + k4 * TWO_PI, q5, q6 + k6 * TWO_PI])
                if np.all(q >= lo) and np.all(q <= hi):
                    solutions.append(q)
    return [q for q in solutions if _pose_error_m(fk_flange(robot, q), X_WF) < tol_m]


def _pose_error_m(X_a: np.ndarray, X_b: np.ndarray) -> float:
    """Translation error plus rotation error expressed at 1 m lever (for verification only)."""
    return float(
        np.linalg.norm(X_a[:3, 3] - X_b[:3, 3]) + np.linalg.norm(X_a[:3, :3] - X_b[:3, :3])
    )


# --- the RX60 as an Arm ------------------------------------------------------------------------


def add_rx60(plant: MultibodyPlant, robot: RX60):
    """The RX60's URDF in `plant`, its base_link welded at the world origin; its model instance."""
    from pydrake.multibody.parsing import Parser

    (instance,) = Parser(plant).AddModelsFromString(rx60_urdf(robot), "urdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base_link", instance))
    return instance


def rx60_arm(robot: RX60 = RX60()) -> Arm:
    """`robot` behind the Arm interface: closed-form FK and IK, the URDF of rx60_urdf."""
    from pydrake.math import RigidTransform

    from robots.arms.arm import Arm

    def ik(X_WF: RigidTransform, q_near: np.ndarray | None = None) -> np.ndarray:
        solutions = ik_flange(robot, X_WF.GetAsMatrix4(), q_near)
        return np.array(solutions).reshape(len(solutions), len(robot.joint_names))

    return Arm(
        name=ROBOT_MODEL_NAME,
        joint_names=robot.joint_names,
        lower=robot.lower,
        upper=robot.upper,
        velocity=np.array(robot.velocity_limits_rad_s),
        acceleration=np.array(robot.acceleration_limits_rad_s2),
        flange_frame=FLANGE_FRAME,
        add_model=lambda plant: add_rx60(plant, robot),
        X_WF=lambda q: RigidTransform(fk_flange(robot, q)),
        ik=ik,
        model_text=rx60_urdf(robot),
        identity=repr(robot),
        accuracy_m=ACCURACY_M,
        repeatability_m=REPEATABILITY_M,
        # The closed form, not a chain read from the URDF: the same kinematics, and the RX60's
        # link lengths by their datasheet names.
        error_model=lambda: arm_model(robot),
        chain=rx60_chain(robot),
        # The wrist sphere is centred on the J6 axis: its distance to anything on the flange is a
        # constant 6 mm, which any planning padding >= 6 mm would turn into a permanent false
        # self-collision. (Parent/child pairs are filtered by the plant; this pair is two joints
        # apart.)
        tool_filtered_links=("link5",),
        home=HOME_Q,
    )

"""Inverse kinematics of the RX60: closed form over all branches, and look-at camera poses.

The RX60 has a spherical wrist, so the wrist centre p_WW = p_WF - L6 z_F fixes q1..q3 (shoulder
left/right x elbow up/down: up to 4 branches) and the wrist orientation R_36 = Rz(q4) Ry(q5)
Rz(q6) fixes q4..q6 (wrist flip: 2 branches). J4 and J6 range over +-270 deg, so each branch also
appears shifted by +-2 pi where the limits allow. Every solution is verified by the same
closed-form forward kinematics before it is returned.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from reconstruction.calibration.robot_errors import ArmModel
from robots.models.rx60 import LINK_LENGTHS, RX60

TWO_PI = 2 * math.pi
# Below this sin(q5) the wrist is singular: q4 + q6 is fixed, q4 is taken from the seed.
WRIST_SINGULAR_EPS = 1e-9


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

    return ArmModel(flange_pose, fields, tuple(LINK_LENGTHS.values()))


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


@dataclass(frozen=True)
class Viewpoint:
    """Where the stereo rig should be: rig centre p_WM (m), the point it looks at p_WT (m), and
    the roll about the optical axis (rad; 0 = image x axis horizontal)."""

    p_WM: tuple[float, float, float]
    p_WT: tuple[float, float, float]
    roll_rad: float = 0.0

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.p_WT, self.p_WM)))


def look_at_rotation(p_WM: np.ndarray, p_WT: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """R_WM with +z towards the target and, at zero roll, +x horizontal (+y pointing down)."""
    z = np.asarray(p_WT, float) - np.asarray(p_WM, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-6:  # looking straight up or down: any horizontal x will do
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z])
    return R @ _rz(roll_rad)


def camera_pose(viewpoint: Viewpoint, X_MC: np.ndarray) -> np.ndarray:
    """X_WC of the left optical frame when the rig centre M looks at the target.

    Aiming the rig centre (not the left camera) keeps the target where both cameras see it and
    away from the left image's columns without disparity search (those left of
    min_disparity + num_disparities have no match in the right image).
    """
    X_WM = np.eye(4)
    X_WM[:3, :3] = look_at_rotation(
        np.array(viewpoint.p_WM), np.array(viewpoint.p_WT), viewpoint.roll_rad
    )
    X_WM[:3, 3] = viewpoint.p_WM
    return X_WM @ X_MC


def rig_centre_offset(X_CR: np.ndarray) -> np.ndarray:
    """X_MC: the left camera frame seen from the rig centre M (midway to the right camera)."""
    X_MC = np.eye(4)
    X_MC[:3, 3] = -X_CR[:3, 3] / 2
    return X_MC


def ik_camera(
    robot: RX60, X_WC: np.ndarray, X_FC: np.ndarray, q_seed: np.ndarray | None = None
) -> list[np.ndarray]:
    """All joint solutions within limits placing the camera frame C at X_WC."""
    return ik_flange(robot, X_WC @ np.linalg.inv(X_FC), q_seed)

"""Camera poses and the joints that reach them: look-at viewpoints, the rig centre, and the
arm's IK of the camera frame (the arm solves for its flange; robots/arms)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from robots.arms.arm import Arm


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


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


def look_at_rotation(
    p_WM: np.ndarray, p_WT: np.ndarray, roll_rad: float = 0.0, up_W=(0.0, 0.0, 1.0)
) -> np.ndarray:
    """R_WM with +z towards the target and, at zero roll, +x horizontal (+y pointing down);
    `up_W`: what counts as up (+y then points away from it)."""
    z = np.asarray(p_WT, float) - np.asarray(p_WM, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up_W, float))
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
    arm: Arm, X_WC: np.ndarray, X_FC: np.ndarray, q_seed: np.ndarray | None = None
) -> list[np.ndarray]:
    """All joint solutions within limits placing the camera frame C at X_WC, in the arm's
    order; `q_seed`: the arm's present joints (see robots.arms.arm.IkSolver)."""
    # Imported here: the command line's parser reads Viewpoint and must not wait for Drake.
    from pydrake.math import RigidTransform

    X_WF = X_WC @ np.linalg.inv(X_FC)
    return list(arm.ik(RigidTransform(X_WF), q_seed))

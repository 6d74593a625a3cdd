"""Laying the object on the support table: the simulated person who puts it down.

The first pass: the object put down as configured settles on the face of its hull nearest
underneath (a stable resting pose, robots/models/table.py). Between passes the scanner asks
for the object to be laid on another face, named by the direction (in the cell frame, of the
object as it lies now) that must face down; the simulated person turns the object so, lets
go, and it settles on the stable face nearest that direction, up to 5 mm off the table's
centre, drawn from the seed. Asked also which side to turn towards the robot (`toward_W`), the
person turns it about the vertical so, by eye: within `MAX_YAW_ERROR_RAD` either way; not asked,
at any turn about the vertical. Without an instruction (a fixed number of passes) the person
turns it upside down: the side facing up now faces down. The software is never told the
result.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from reconstruction.common.transforms import rotation_about, rotation_between
from reconstruction.hangings.resting_poses import RestingPose, centre_of_mass, resting_poses
from robots.models.table import lying_pose, nearest_pose

# How far off the table's centre a person puts the object down (a glance, not a measurement).
MAX_OFFSET_M = 0.005
# How far off the asked heading a person turns the object by eye (a side "towards the robot").
MAX_YAW_ERROR_RAD = math.radians(20.0)
UP = np.array([0.0, 0.0, 1.0])


@lru_cache(maxsize=4)
def _poses_of(vertices_key: bytes, triangles_key: bytes, shape: tuple) -> tuple:
    v = np.frombuffer(vertices_key).reshape(shape)
    t = np.frombuffer(triangles_key, dtype=np.int64).reshape(-1, 3)
    com = centre_of_mass(v, t)
    return resting_poses(v, com), com


def stable_poses(mesh) -> tuple[tuple[RestingPose, ...], np.ndarray]:
    """The true mesh's stable resting poses (object frame) and its centre of mass."""
    v = np.ascontiguousarray(mesh.vertices, float)
    t = np.ascontiguousarray(mesh.triangles, np.int64)
    return _poses_of(v.tobytes(), t.tobytes(), v.shape)


def first_lying_pose(cell, mesh) -> np.ndarray:
    """X_WO of the first pass: the configured orientation settled on the face underneath."""
    poses, com = stable_poses(mesh)
    R_WO = np.asarray(cell.X_WO, float)[:3, :3]
    pose = nearest_pose(poses, R_WO.T @ -UP)
    # Only the settling turns it: the smallest turn from the configured orientation.
    R = rotation_between(R_WO @ pose.down_O, -UP) @ R_WO
    return lying_pose(cell, R, mesh.vertices, com)


def laid_pose(
    cell, mesh, X_WO_now: np.ndarray, down_W, seed: int, index: int, toward_W=None
) -> np.ndarray:
    """X_WO after the person laid the object for pass `index`, asked to put the side facing
    `down_W` (cell frame, as it lies now; None: turn it upside down) underneath, and, with
    `toward_W` (as it lies now), to turn the side facing that way towards the robot."""
    poses, com = stable_poses(mesh)
    R_now = np.asarray(X_WO_now, float)[:3, :3]
    asked_W = UP if down_W is None else np.asarray(down_W, float)
    pose = nearest_pose(poses, R_now.T @ asked_W)
    rng = np.random.default_rng([seed, 6151, index])
    yaw = rng.uniform(0.0, 2 * math.pi)
    azimuth = rng.uniform(0.0, 2 * math.pi)
    offset = rng.uniform(0.0, MAX_OFFSET_M)
    R_down = rotation_between(R_now @ pose.down_O, -UP)
    if toward_W is not None:
        # The asked side, once laid, turned to face the robot (at the origin, the object in
        # front of it along +x), by eye.
        t = R_down @ np.asarray(toward_W, float)
        heading = math.atan2(t[1], t[0]) if math.hypot(t[0], t[1]) > 1e-6 else 0.0
        error = (yaw / math.pi - 1.0) * MAX_YAW_ERROR_RAD  # the same draw, within the error
        yaw = math.pi - heading + error
    R = rotation_about(UP, yaw) @ R_down @ R_now
    shift = (offset * math.cos(azimuth), offset * math.sin(azimuth))
    return lying_pose(cell, R, mesh.vertices, com, shift)

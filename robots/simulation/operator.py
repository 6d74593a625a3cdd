"""Re-hanging the object between passes of a scan: the simulator's new orientations.

A hung object shows the robot a cap below and around it; its top stays unseen. Scanning
practice re-hangs (flips) it and scans again. The simulator draws each pass's orientation from
the error model's seed: a tilt of 90-180 deg about a random horizontal axis, then any turn
about the vertical; pass 0 is the configured hanging. The software is never told these.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction.common.transforms import rotation_about

MIN_TILT_RAD = math.radians(90.0)
MAX_TILT_RAD = math.radians(180.0)


def hanging_rotation(seed: int, hanging: int) -> np.ndarray:
    """R (3x3, in the cell frame, about the object's centre) of hanging `hanging` (0: none)."""
    if hanging == 0:
        return np.eye(3)
    rng = np.random.default_rng([seed, 7919, hanging])
    azimuth = rng.uniform(0.0, 2 * math.pi)
    axis = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    tilt = rng.uniform(MIN_TILT_RAD, MAX_TILT_RAD)
    yaw = rng.uniform(0.0, 2 * math.pi)
    return rotation_about(np.array([0.0, 0.0, 1.0]), yaw) @ rotation_about(axis, tilt)


def hung_pose(X_WO: np.ndarray, seed: int, hanging: int) -> np.ndarray:
    """The object's pose in hanging `hanging`: the configured pose turned about its centre."""
    X = np.array(X_WO, float)
    X[:3, :3] = hanging_rotation(seed, hanging) @ X[:3, :3]
    return X

"""Re-hanging the object between passes of a scan: the simulated operator.

A hung object shows the robot a cap below and around it; its top stays unseen. Scanning
practice re-hangs (turns) it and scans again. The scanner says how ("the side now facing
there must point up"); the simulated operator follows the instruction the way a person does:
10-25 deg off the requested orientation about a random horizontal axis, and at any turn about
the vertical (nobody is told the yaw), clamped at its new top. The `random` operator ignores
the instruction and tilts the object 90-180 deg about a random horizontal axis, then any turn
about the vertical (the worst case for benchmarks; also the hanging of a scan with a fixed
number of hangings). Pass 0 is the configured hanging. The software is never told the result.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction.common.transforms import rotation_about, rotation_between

MIN_TILT_RAD = math.radians(90.0)
MAX_TILT_RAD = math.radians(180.0)
# How far off a person hangs the object from what was asked.
MIN_OPERATOR_ERROR_RAD = math.radians(10.0)
MAX_OPERATOR_ERROR_RAD = math.radians(25.0)
OPERATORS = ("instructed", "random")
UP = np.array([0.0, 0.0, 1.0])


def rotation_to_up(direction: np.ndarray) -> np.ndarray:
    """The smallest turn R (3x3) that brings `direction` (cell frame, z up) to the top."""
    return rotation_between(direction, UP)


def instructed_rotation(seed: int, hanging: int, up_W: np.ndarray) -> np.ndarray:
    """The turn R (3x3, in the cell frame about the object's centre) a person makes when asked
    to bring the direction `up_W` (of the object as it hangs now) to the top: the requested
    turn, then 10-25 deg off about a random horizontal axis, then any yaw."""
    rng = np.random.default_rng([seed, 104729, hanging])
    azimuth = rng.uniform(0.0, 2 * math.pi)
    axis = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    error = rng.uniform(MIN_OPERATOR_ERROR_RAD, MAX_OPERATOR_ERROR_RAD)
    yaw = rng.uniform(0.0, 2 * math.pi)
    return rotation_about(UP, yaw) @ rotation_about(axis, error) @ rotation_to_up(up_W)


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
    """The object's pose in hanging `hanging` by the random operator: the configured pose
    turned about its centre."""
    X = np.array(X_WO, float)
    X[:3, :3] = hanging_rotation(seed, hanging) @ X[:3, :3]
    return X


def rehung_pose(
    X_WO_now: np.ndarray, X_WO_first: np.ndarray, seed: int, hanging: int, operator: str, up_W
) -> np.ndarray:
    """The object's pose after the operator re-hung it for pass `hanging`, asked to bring
    `up_W` (None: no instruction) of the object as it hangs now (`X_WO_now`) to the top."""
    if operator == "random" or up_W is None:
        return hung_pose(X_WO_first, seed, hanging)
    X = np.array(X_WO_now, float)
    X[:3, :3] = instructed_rotation(seed, hanging, up_W) @ X[:3, :3]
    return X

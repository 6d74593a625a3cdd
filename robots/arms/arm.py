"""One arm as the rest of the product sees it: joints, limits, flange, FK and IK, accuracy.

FK and IK are callables, so that an arm with a closed-form solver can stand behind the same
record as one solved numerically from its model file.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.math import RigidTransform

from robots.arms.arm_file import ArmFile, read_arm_file
from robots.arms.general_ik import solve_ik
from robots.arms.model import ArmPlant, load_arm_plant


@dataclass(frozen=True, eq=False)
class Arm:
    """A serial arm. Arrays per joint in `joint_names` order (base to flange), read-only:
    position limits (rad, or m for a prismatic joint), velocity (rad/s), acceleration (rad/s^2).
    `X_WF(q)`: the flange frame F in the world. `ik(X_WF)`: every solution found, (k, n), sorted.
    accuracy_m / repeatability_m: the vendor's pose accuracy and repeatability."""

    name: str
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    flange_frame: str
    X_WF: Callable[[np.ndarray], RigidTransform]
    ik: Callable[[RigidTransform], np.ndarray]
    accuracy_m: float
    repeatability_m: float


def arm_from_plant(arm_file: ArmFile, plant: ArmPlant) -> Arm:
    def ik(X_WF: RigidTransform) -> np.ndarray:
        return solve_ik(plant, X_WF, arm_file.ik)

    return Arm(
        name=arm_file.name,
        joint_names=plant.joint_names,
        lower=plant.lower,
        upper=plant.upper,
        velocity=plant.velocity,
        acceleration=plant.acceleration,
        flange_frame=arm_file.flange_link,
        X_WF=plant.X_WF,
        ik=ik,
        accuracy_m=arm_file.accuracy_m,
        repeatability_m=arm_file.repeatability_m,
    )


def load_arm(spec: Path | str) -> Arm:
    """The arm of an arm file (its path). ScannerError, one line, for any fault in the file."""
    arm_file = read_arm_file(spec)
    return arm_from_plant(arm_file, load_arm_plant(arm_file))


def load_arm_file(path: Path | str) -> ArmFile:
    """A fully checked arm file: its fields, and against its model the flange link and a limit
    for every joint (from the model or the file). Raises ScannerError, one line."""
    arm_file = read_arm_file(path)
    load_arm_plant(arm_file)
    return arm_file

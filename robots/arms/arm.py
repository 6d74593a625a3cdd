"""One arm as the rest of the product sees it: joints, limits, its Drake model and flange, FK and
IK, accuracy. Planning and the work cell ask an `Arm` and name no model.

FK, IK and adding the model to a plant are callables, so that an arm with a closed-form solver
(the RX60, robots/arms/rx60.py) stands behind the same record as one solved numerically from its
arm file (`load_arm`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex

from reconstruction.calibration.joint_chain import JointChain, chain_arm_model
from reconstruction.calibration.robot_errors import ArmModel
from robots.arms.arm_file import ArmFile, read_arm_file
from robots.arms.chain import joint_chain
from robots.arms.general_ik import solve_ik
from robots.arms.limits import within_limits
from robots.arms.model import ArmPlant, add_arm_model, load_arm_plant, model_text


class IkSolver(Protocol):
    def __call__(self, X_WF: RigidTransform, q_near: np.ndarray | None = None) -> np.ndarray:
        """Every distinct joint vector (k, n) within the limits that puts the flange frame F at
        X_WF, in an order fixed by the arm; (0, n) when there is none. `q_near`: the arm's
        present joints, which a solver may use to pick a point of a continuum (the RX60 keeps
        its J4 at a singular wrist)."""
        ...


@dataclass(frozen=True, eq=False)
class Arm:
    """A serial arm. Arrays per joint in `joint_names` order (base to flange), read-only:
    position limits (rad, or m for a prismatic joint), velocity (rad/s), acceleration (rad/s^2).

    `add_model(plant)`: adds the arm, its root welded in the world, to an unfinalised plant and
    returns its model instance; `flange_frame` names the flange frame F in that instance.
    `X_WF(q)`: F in the world. `ik`: see IkSolver. `model_text` (the model as the plant reads
    it) and `identity` (every other number that defines the arm) key what is cached for it.
    `tool_filtered_links`: links never checked against the tool on the flange (a link whose
    distance to the tool cannot change with q would otherwise be a permanent false collision
    under the planning padding). accuracy_m / repeatability_m: the vendor's pose accuracy and
    repeatability. `home`: where a simulated arm starts and a scan begins, collision-free in the
    work cell (None: the middle of every joint's range; see `home_q`). `error_model()`: its
    kinematics with the error parameters a calibration estimates (joint zero offsets, link
    lengths; reconstruction/calibration/robot_errors.py), `arm_name` set to `name`. `chain`:
    its joints as numbers (each joint's fixed transform from the previous one and its axis)."""

    name: str
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    flange_frame: str
    add_model: Callable[[MultibodyPlant], ModelInstanceIndex]
    X_WF: Callable[[np.ndarray], RigidTransform]
    ik: IkSolver
    model_text: str
    identity: str
    accuracy_m: float
    repeatability_m: float
    error_model: Callable[[], ArmModel]
    chain: JointChain
    tool_filtered_links: tuple[str, ...] = ()
    home: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        for name in ("lower", "upper", "velocity", "acceleration"):
            value = np.array(getattr(self, name), float)
            if value.shape != (len(self.joint_names),):
                raise ValueError(f"arm {self.name}: {name} must have one value per joint")
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if self.home is not None and not (
            len(self.home) == self.joint_count and self.within_limits(np.array(self.home))
        ):
            raise ValueError(f"arm {self.name}: home must be one value per joint, within limits")

    @property
    def home_q(self) -> np.ndarray:
        """The home configuration (n,): `home`, else the middle of every joint's range (the
        arm's own model is its only guide then; an arm file names a home where that middle
        collides with the cell)."""
        if self.home is not None:
            return np.array(self.home, float)
        return 0.5 * (self.lower + self.upper)

    @property
    def joint_count(self) -> int:
        return len(self.joint_names)

    def within_limits(self, q: np.ndarray, tol_rad: float = 1e-9) -> bool:
        return within_limits(q, self.lower, self.upper, tol_rad)


def arm_from_plant(arm_file: ArmFile, plant: ArmPlant, model: tuple[str, str]) -> Arm:
    """The arm of a parsed arm file; `model`: (text, "urdf" or "sdf") it was parsed from."""

    def ik(X_WF: RigidTransform, q_near: np.ndarray | None = None) -> np.ndarray:
        # The numerical solver returns every solution it finds; where the arm is does not matter.
        return solve_ik(plant, X_WF, arm_file.ik)

    def add_model(target: MultibodyPlant) -> ModelInstanceIndex:
        return add_arm_model(target, arm_file, *model)

    chain = joint_chain(plant, arm_file.name)

    return Arm(
        name=arm_file.name,
        joint_names=plant.joint_names,
        lower=plant.lower,
        upper=plant.upper,
        velocity=plant.velocity,
        acceleration=plant.acceleration,
        flange_frame=arm_file.flange_link,
        add_model=add_model,
        X_WF=plant.X_WF,
        ik=ik,
        model_text=model[0],
        identity=repr(arm_file),
        accuracy_m=arm_file.accuracy_m,
        repeatability_m=arm_file.repeatability_m,
        error_model=lambda: chain_arm_model(chain),
        chain=chain,
        home=arm_file.home_q_rad,
    )


def load_arm(spec: Path | str) -> Arm:
    """The arm of an arm file (its path). ScannerError, one line, for any fault in the file."""
    arm_file = read_arm_file(spec)
    model = model_text(arm_file)
    return arm_from_plant(arm_file, load_arm_plant(arm_file, model), model)


def load_arm_file(path: Path | str) -> ArmFile:
    """A fully checked arm file: its fields, and against its model the flange link and a limit
    for every joint (from the model or the file). Raises ScannerError, one line."""
    arm_file = read_arm_file(path)
    load_arm_plant(arm_file)
    return arm_file

"""Forward kinematics of an arm from its Drake model, without a scene graph or renderer."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import MultibodyPlant

from robots.arms.arm import Arm
from robots.arms.default import DEFAULT_ARM
from robots.arms.rx60 import RX60, rx60_arm


class Kinematics:
    """X_WF(q) of the flange; X_WC(q) = X_WF(q) @ X_FC for any hand-eye transform."""

    def __init__(self, arm: Arm = DEFAULT_ARM) -> None:
        self.arm = arm
        self._plant = MultibodyPlant(0.0)
        instance = arm.add_model(self._plant)
        self._plant.Finalize()
        self._context = self._plant.CreateDefaultContext()
        self._flange = self._plant.GetFrameByName(arm.flange_frame, instance)

    def X_WF(self, q: np.ndarray) -> np.ndarray:
        self._plant.SetPositions(self._context, np.asarray(q, dtype=float))
        return self._flange.CalcPoseInWorld(self._context).GetAsMatrix4()

    def X_WC(self, q: np.ndarray, X_FC: np.ndarray) -> np.ndarray:
        return self.X_WF(q) @ X_FC


def corrected_kinematics(joint_offsets_rad, link_length_corrections_m: dict[str, float]):
    """X_WF(q) of the RX60 with a calibration's joint zero offsets (true = reported + offset)
    and link length corrections ({RX60 field: metres}) applied to the reported joints q."""
    kinematics = Kinematics(rx60_arm(RX60().with_length_corrections(link_length_corrections_m)))
    offsets = np.array(joint_offsets_rad, float)
    return lambda q: kinematics.X_WF(np.asarray(q, float) + offsets)

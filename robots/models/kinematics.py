"""Forward kinematics of the RX60 from its URDF, without a scene graph or renderer."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import MultibodyPlant

from robots.models.rx60 import FLANGE_FRAME, RX60
from robots.models.workcell import add_rx60


class Kinematics:
    """X_WF(q) of the flange; X_WC(q) = X_WF(q) @ X_FC for any hand-eye transform."""

    def __init__(self, robot: RX60 = RX60()) -> None:
        self.robot = robot
        self._plant = MultibodyPlant(0.0)
        instance = add_rx60(self._plant, robot)
        self._plant.Finalize()
        self._context = self._plant.CreateDefaultContext()
        self._flange = self._plant.GetFrameByName(FLANGE_FRAME, instance)

    def X_WF(self, q: np.ndarray) -> np.ndarray:
        self._plant.SetPositions(self._context, np.asarray(q, dtype=float))
        return self._flange.CalcPoseInWorld(self._context).GetAsMatrix4()

    def X_WC(self, q: np.ndarray, X_FC: np.ndarray) -> np.ndarray:
        return self.X_WF(q) @ X_FC


def corrected_kinematics(joint_offsets_rad, link_length_corrections_m: dict[str, float]):
    """X_WF(q) of the RX60 with a calibration's joint zero offsets (true = reported + offset)
    and link length corrections ({RX60 field: metres}) applied to the reported joints q."""
    kinematics = Kinematics(RX60().with_length_corrections(link_length_corrections_m))
    offsets = np.array(joint_offsets_rad, float)
    return lambda q: kinematics.X_WF(np.asarray(q, float) + offsets)

"""Forward kinematics of an arm from its Drake model, without a scene graph or renderer."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import MultibodyPlant

from reconstruction.calibration.file import RobotCorrection
from reconstruction.common.errors import ScannerError
from robots.arms.arm import Arm
from robots.arms.default import DEFAULT_ARM


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


def corrected_kinematics(arm: Arm, correction: RobotCorrection, where: str):
    """X_WF(q) (4x4) of `arm` with a calibration's joint zero offsets (true = reported +
    offset) and link length corrections (by the arm's error model's keys) applied to the
    reported joints q. ScannerError, one line starting with `where` (the file's field or flag),
    when the correction is another arm's or does not fit this arm's parameters."""
    if correction.arm != arm.name:
        raise ScannerError(
            f"{where}: its joint offsets and link lengths are arm {correction.arm}'s, this arm "
            f"is {arm.name}: calibrate {arm.name} with --robot-offsets, or calibrate without it"
        )
    model = arm.error_model()
    unknown = sorted(set(correction.link_length_corrections_m) - set(model.length_keys))
    if len(correction.joint_offsets_rad) != model.joint_count or unknown:
        raise ScannerError(
            f"{where}: its robot correction does not fit arm {arm.name} (expected "
            f"{model.joint_count} joint offsets and lengths among "
            f"{', '.join(model.length_keys) or 'none'}; got "
            f"{len(correction.joint_offsets_rad)} offsets, lengths {', '.join(unknown)})"
        )
    p = np.zeros(model.size)
    p[: model.joint_count] = correction.joint_offsets_rad
    for key, value in correction.link_length_corrections_m.items():
        p[model.joint_count + model.length_keys.index(key)] = value
    return lambda q: model.flange_pose(np.asarray(q, float), p)

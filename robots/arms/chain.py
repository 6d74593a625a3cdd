"""An arm's Drake model as the numeric joint chain a calibration estimates its errors on
(reconstruction/calibration/joint_chain.py), read from the plant at q = 0."""

from __future__ import annotations

import numpy as np

from reconstruction.calibration.joint_chain import JointChain
from reconstruction.common.transforms import invert
from robots.arms.model import ArmPlant


def joint_chain(arm: ArmPlant, arm_name: str) -> JointChain:
    """The chain of `arm`'s movable joints, base to flange. At q = 0 every joint's moving frame
    M coincides with its fixed frame F, so the fixed transform between two joints is the pose of
    one's F in the other's M there, whatever welded links lie between them."""
    plant = arm.plant
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, np.zeros(plant.num_positions()))
    joints = [plant.GetJointByName(name) for name in arm.joint_names]
    X_WM_previous = np.eye(4)
    X_MF, axes = [], []
    for joint in joints:
        X_WF = joint.frame_on_parent().CalcPoseInWorld(context).GetAsMatrix4()
        X_MF.append(invert(X_WM_previous) @ X_WF)
        X_WM_previous = joint.frame_on_child().CalcPoseInWorld(context).GetAsMatrix4()
        revolute = joint.type_name() == "revolute"
        axes.append(np.asarray(joint.revolute_axis() if revolute else joint.translation_axis()))
    X_WFlange = arm.flange_frame.CalcPoseInWorld(context).GetAsMatrix4()
    X_MF.append(invert(X_WM_previous) @ X_WFlange)
    return JointChain(
        arm_name,
        arm.joint_names,
        arm.flange_frame.name(),
        np.array(X_MF),
        np.array(axes),
        np.array(arm.revolute, bool),
    )

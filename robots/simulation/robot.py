"""A simulated arm: kinematic playback of trajectories, encoder offsets from the truth."""

from __future__ import annotations

import numpy as np

from robots.arms.arm import Arm
from robots.drivers.interfaces import JointTrajectory, RobotDriver

# A trajectory must start where the arm is; a larger jump means a planning bug, not noise.
START_TOLERANCE_RAD = 1e-6


class SimulatedRobot(RobotDriver):
    """Measured joints are what the controller believes; the true arm is offset by the encoders'
    zero errors (true = measured + offset)."""

    def __init__(self, arm: Arm, joint_offsets_rad: np.ndarray, q0: np.ndarray) -> None:
        self.arm = arm
        self._offsets = np.asarray(joint_offsets_rad, float)
        self._q = np.asarray(q0, float).copy()
        if self._offsets.shape != (arm.joint_count,) or self._q.shape != (arm.joint_count,):
            raise ValueError(f"{arm.name}: offsets and q0 need {arm.joint_count} joints each")
        if not arm.within_limits(self._q):
            raise ValueError(f"initial configuration outside joint limits: {self._q}")
        self.executed: list[JointTrajectory] = []
        self.motion_time_s = 0.0

    def joint_positions(self) -> np.ndarray:
        return self._q.copy()

    def true_joint_positions(self) -> np.ndarray:
        return self._q + self._offsets

    def teleport(self, q: np.ndarray) -> None:
        """Place the arm without moving it (simulation set-up and previews only)."""
        q = np.asarray(q, float)
        if not self.arm.within_limits(q):
            raise ValueError(f"configuration outside joint limits: {q}")
        self._q = q.copy()

    def execute(self, trajectory: JointTrajectory) -> None:
        q = trajectory.positions_rad
        if np.max(np.abs(q[0] - self._q)) > START_TOLERANCE_RAD:
            raise ValueError("trajectory does not start at the current joint positions")
        if not all(self.arm.within_limits(qi) for qi in q):
            raise ValueError("trajectory leaves the joint limits")
        self.executed.append(trajectory)
        self.motion_time_s += trajectory.duration_s
        self._q = q[-1].copy()

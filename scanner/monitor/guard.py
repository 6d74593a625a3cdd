"""The arm and the camera behind the cell monitor: drivers that let the scan's decision maker
run unchanged while every motion and capture is watched.

An intrusion during a motion stops the arm at the next sample of its trajectory (every sample
lies on the path that was checked collision-free), waits until the cell has been clear for
`clear_time_s`, then plans again from where the arm stands to the same goal (collision-checked
and time-parameterised from rest, as any motion) and goes on, watched. Before a capture the cell
is watched with the arm still; a capture waits while it is not clear.
"""

from __future__ import annotations

import numpy as np

from planners.planner import PlanFailure
from robots.drivers.interfaces import JointTrajectory, RobotDriver, StereoCameraDriver, StereoImages
from scanner.monitor.cell_monitor import CellMonitor, MonitorStoppedError


class MonitoredRobot(RobotDriver):
    def __init__(self, inner: RobotDriver, monitor: CellMonitor, planner) -> None:
        """`planner`: plans a new motion (`plan`) and makes it what `inner` runs
        (`executable`), as for any motion of the scan."""
        self.inner, self.monitor, self._planner = inner, monitor, planner
        self.motion = inner.motion
        self.pauses = 0

    def joint_positions(self) -> np.ndarray:
        return self.inner.joint_positions()

    def execute(self, trajectory: JointTrajectory) -> None:
        t0 = self.monitor.video.clock_s
        stop = self.monitor.watch_motion(trajectory)
        if stop is None:
            self.inner.execute(trajectory)
            return
        times = trajectory.times_s
        k = max(1, int(np.searchsorted(times, stop - 1e-9)))
        if k < len(times) - 1:
            # A prefix of a checked joint-linear path is a checked joint-linear path.
            head = JointTrajectory(
                times[: k + 1], trajectory.positions_rad[: k + 1], trajectory.joint_linear
            )
            self.inner.execute(head)
        else:
            self.inner.execute(trajectory)
        self.pauses += 1
        # The arm comes to rest at sample k; the video goes on from there.
        self.monitor.video.clock_s = max(self.monitor.video.clock_s, t0 + float(times[k]))
        q = self.inner.joint_positions()
        self.monitor.event(self.monitor.video.clock_s, "paused", "arm stopped on its path")
        self.monitor.wait_until_clear(q)
        goal = trajectory.positions_rad[-1]
        if np.max(np.abs(q - goal)) <= 1e-9:
            return
        result = self._planner.plan(q, goal)
        if not isinstance(result, PlanFailure):
            result = self._planner.executable(result, self.motion)
        if isinstance(result, PlanFailure):
            raise MonitorStoppedError(
                f"after an intrusion no path from where the arm stopped to its goal "
                f"({result.reason}: {result.detail}); the scan stops here and can be resumed"
            )
        self.monitor.event(self.monitor.video.clock_s, "resumed", "motion planned again")
        self.execute(result)


class MonitoredCamera(StereoCameraDriver):
    def __init__(self, inner: StereoCameraDriver, robot: RobotDriver, monitor: CellMonitor):
        self.inner, self.robot, self.monitor = inner, robot, monitor
        self.capture_times_s: list[float] = []

    def capture(self) -> StereoImages:
        q = self.robot.joint_positions()
        dwell = self.monitor.settings.capture_dwell_s
        while not self.monitor.watch_rest(q, dwell):
            self.monitor.event(self.monitor.video.clock_s, "paused", "capture held")
            self.monitor.wait_until_clear(q)
            self.monitor.event(self.monitor.video.clock_s, "resumed", "capture")
        self.capture_times_s.append(self.monitor.video.clock_s)
        return self.inner.capture()

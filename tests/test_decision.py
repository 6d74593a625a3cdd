"""The decision maker's state machine with stand-in planner and camera (no simulator needed)."""

from dataclasses import dataclass

import numpy as np

from planners.ik import Viewpoint
from planners.planner import PlanFailure
from robots.arms.default import DEFAULT_ARM
from robots.drivers.interfaces import (
    CaptureError,
    JointTrajectory,
    StereoCameraDriver,
    StereoImages,
)
from robots.simulation.robot import SimulatedRobot
from scanner.scan.decision import DecisionMaker, FixedViewList, State
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.views import PlannedView, ViewOption


@dataclass
class _Straight:
    q_a: np.ndarray
    q_b: np.ndarray
    duration_s: float = 1.0

    def to_joint_trajectory(self):
        return JointTrajectory(np.array([0.0, self.duration_s]), np.stack([self.q_a, self.q_b]))


class _Planner:
    def __init__(self, blocked):
        self.blocked = blocked  # goals (rounded tuples) the planner cannot reach
        self.calls = 0

    def plan(self, q_start, q_goal):
        self.calls += 1
        if tuple(np.round(q_goal, 6)) in self.blocked:
            return PlanFailure("no_path", "stand-in planner refuses this goal")
        return _Straight(q_start, q_goal)

    def estimate_duration_s(self, q_a, q_b):
        return 1.0

    def executable(self, trajectory, motion):
        return trajectory.to_joint_trajectory()


class _Camera(StereoCameraDriver):
    def __init__(self, failures_before_success=0, always_fail=False):
        self.failures = failures_before_success
        self.always_fail = always_fail
        self.calls = 0

    def capture(self):
        self.calls += 1
        if self.always_fail or self.failures > 0:
            self.failures -= 1
            raise CaptureError("stand-in camera timeout")
        img = np.full((8, 8, 3), self.calls, np.uint8)
        return StereoImages(img, img, float(self.calls))


def _view(i, *qs):
    return PlannedView(
        i,
        np.zeros(3),
        Viewpoint((0, 0, 0), (1, 0, 0)),
        tuple(ViewOption(0.0, np.asarray(q, float)) for q in qs),
    )


def _machine(tmp_path, views, planner, camera):
    robot = SimulatedRobot(DEFAULT_ARM, np.zeros(6), np.zeros(6))
    store = CaptureStore.create(tmp_path / "scan", {})
    return DecisionMaker(
        planner, robot, camera, store, FixedViewList(list(views)), len(views), lambda q: np.eye(4)
    ), store


def test_unreachable_view_is_skipped_and_the_scan_goes_on(tmp_path):
    q1, q2a, q2b, q3 = ([0.1 * k, 0, 0, 0, 0, 0] for k in (1, 2, 3, 4))
    planner = _Planner(blocked={tuple(np.round(q2a, 6)), tuple(np.round(q2b, 6))})
    views = [_view(0, q1), _view(1, q2a, q2b), _view(2, q3)]
    machine, store = _machine(tmp_path, views, planner, _Camera())
    summary = machine.run()
    assert summary.state is State.DONE
    assert summary.captured == [0, 2]
    (skipped,) = summary.skipped
    assert skipped.index == 1 and "no_path" in skipped.reason and skipped.attempts == 2
    assert store.captured_indices() == [0, 2]
    assert ("plan", "skip") in summary.transitions
    assert summary.robot_motion_s == 2.0


def test_second_ik_branch_is_tried_after_a_plan_failure(tmp_path):
    blocked_q, ok_q = [0.5, 0, 0, 0, 0, 0], [0.6, 0, 0, 0, 0, 0]
    planner = _Planner(blocked={tuple(np.round(blocked_q, 6))})
    machine, store = _machine(tmp_path, [_view(0, blocked_q, ok_q)], planner, _Camera())
    summary = machine.run()
    assert summary.captured == [0] and planner.calls == 2
    np.testing.assert_allclose(store.read_capture(0).q_rad, ok_q)


def test_capture_failures_are_retried_then_skipped(tmp_path):
    views = [_view(0, [0.1, 0, 0, 0, 0, 0])]
    machine, _ = _machine(tmp_path, views, _Planner(set()), _Camera(failures_before_success=2))
    assert machine.run().captured == [0]
    views = [_view(0, [0.1, 0, 0, 0, 0, 0])]
    camera = _Camera(always_fail=True)
    machine, store = _machine(tmp_path / "b", views, _Planner(set()), camera)
    summary = machine.run()
    assert summary.captured == [] and "capture failed 3 times" in summary.skipped[0].reason
    assert camera.calls == 3 and store.captured_indices() == []


def test_abort_stops_after_the_current_capture(tmp_path):
    views = [_view(i, [0.1 * i, 0, 0, 0, 0, 0]) for i in range(4)]
    machine, store = _machine(tmp_path, views, _Planner(set()), _Camera())
    machine.on_view_done = lambda outcome: machine.request_abort() if outcome.index == 1 else None
    summary = machine.run()
    assert summary.state is State.ABORTED
    assert store.captured_indices() == [0, 1]

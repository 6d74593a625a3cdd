"""The decision maker: an explicit state machine that visits views and captures stereo pairs.

    START -> CHOOSE_VIEW -> PLAN -> EXECUTE -> SETTLE -> CAPTURE -> PROCESS -> CHOOSE_VIEW ... DONE
    PLAN failure: next option of the view (other roll / IK branch), then SKIP the view
    CAPTURE failure: retry up to `capture_retries` times, then SKIP the view
    abort request (Ctrl-C / SIGTERM): finish the current capture, then ABORTED

Where the views come from is behind `ViewSource`: the fixed tour today, a next-best-view
selector later, without touching the machine.
"""

from __future__ import annotations

import enum
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from planners.planner import PlanFailure
from reconstruction.common.stage_timer import StageTimer
from robots.drivers.interfaces import CaptureError, RobotDriver, StereoCameraDriver
from scanner.configs.scan import MachineConfig
from scanner.scan_dir.captures import Capture, CaptureStore
from scanner.scan_dir.views import PlannedView, ViewOption

log = logging.getLogger("scanner.scan.decision")


class State(enum.Enum):
    START = "start"
    CHOOSE_VIEW = "choose_view"
    PLAN = "plan"
    EXECUTE = "execute"
    SETTLE = "settle"
    CAPTURE = "capture"
    PROCESS = "process"
    SKIP = "skip"
    DONE = "done"
    ABORTED = "aborted"


class PlannerLike(Protocol):
    """What the machine needs of the planner (planners.planner.Planner provides it)."""

    def plan(self, q_start: np.ndarray, q_goal: np.ndarray): ...  # Trajectory | PlanFailure

    def estimate_duration_s(self, q_a: np.ndarray, q_b: np.ndarray) -> float: ...

    def executable(self, trajectory, motion: str): ...  # JointTrajectory | PlanFailure


class ViewSource(Protocol):
    def next_view(self, q_current: np.ndarray) -> PlannedView | None: ...

    def report(self, view: PlannedView, outcome: ViewOutcome) -> None: ...

    def options_in_order(self, view: PlannedView) -> list[ViewOption]: ...


@dataclass(frozen=True)
class ViewOutcome:
    index: int
    captured: bool
    reason: str = ""
    attempts: int = 1
    motion_s: float = 0.0


@dataclass
class FixedViewList:
    """Views in a precomputed order (the tour); the preferred option of each goes first."""

    views: list[PlannedView]
    preferred_option: dict[int, int] = field(default_factory=dict)
    outcomes: list[ViewOutcome] = field(default_factory=list)

    def next_view(self, q_current: np.ndarray) -> PlannedView | None:
        return self.views.pop(0) if self.views else None

    def report(self, view: PlannedView, outcome: ViewOutcome) -> None:
        self.outcomes.append(outcome)

    def options_in_order(self, view: PlannedView) -> list[ViewOption]:
        first = self.preferred_option.get(view.index, 0)
        return [view.options[first]] + [o for k, o in enumerate(view.options) if k != first]


@dataclass
class RunSummary:
    state: State
    outcomes: list[ViewOutcome]
    robot_motion_s: float
    stage_s: dict[str, float]
    transitions: list[tuple[str, str]]

    @property
    def captured(self) -> list[int]:
        return [o.index for o in self.outcomes if o.captured]

    @property
    def skipped(self) -> list[ViewOutcome]:
        return [o for o in self.outcomes if not o.captured]


class DecisionMaker:
    def __init__(
        self,
        planner: PlannerLike,
        robot: RobotDriver,
        camera: StereoCameraDriver,
        store: CaptureStore,
        source: ViewSource,
        pose_count: int,
        X_WF: Callable[[np.ndarray], np.ndarray],
        settings: MachineConfig | None = None,
        process: Callable[[Capture], None] | None = None,
        on_view_done: Callable[[ViewOutcome], None] | None = None,
        settle_poll_s: float = 0.05,
    ) -> None:
        self.planner, self.robot, self.camera, self.store = planner, robot, camera, store
        self.source, self.pose_count = source, pose_count
        self.settings = settings or MachineConfig()
        self.settle_poll_s = settle_poll_s
        self._fk = X_WF
        self.process, self.on_view_done = process, on_view_done
        self.abort_requested = False
        self.state = State.START
        self._transitions: list[tuple[str, str]] = []
        self._timer = StageTimer()
        self._motion_s = 0.0

    def request_abort(self) -> None:
        """Safe from a signal handler: the machine stops at the next state boundary."""
        self.abort_requested = True

    def _go(self, state: State, why: str = "") -> None:
        log.info("%s -> %s%s", self.state.value, state.value, f" ({why})" if why else "")
        self._transitions.append((self.state.value, state.value))
        self.state = state

    def run(self) -> RunSummary:
        outcomes: list[ViewOutcome] = []
        self._go(State.CHOOSE_VIEW)
        while True:
            if self.abort_requested:
                self._go(State.ABORTED, "abort requested")
                break
            view = self.source.next_view(self.robot.joint_positions())
            if view is None:
                self._go(State.DONE, "no more views")
                break
            outcome = self._visit(view)
            outcomes.append(outcome)
            self.source.report(view, outcome)
            if self.on_view_done:
                self.on_view_done(outcome)
            if self.state is not State.CHOOSE_VIEW:
                self._go(State.CHOOSE_VIEW)
        return RunSummary(
            self.state, outcomes, self._motion_s, dict(self._timer.seconds), list(self._transitions)
        )

    def _skip(self, view: PlannedView, reason: str, attempts: int) -> ViewOutcome:
        self._go(State.SKIP, f"view {view.index}: {reason}")
        log.warning("view %d skipped: %s", view.index, reason)
        return ViewOutcome(view.index, False, reason, attempts)

    def _visit(self, view: PlannedView) -> ViewOutcome:
        failures = []
        for attempt, option in enumerate(self.source.options_in_order(view), start=1):
            self._go(State.PLAN, f"view {view.index} option {attempt}")
            q_now = self.robot.joint_positions()
            result = self._timer.call("plan", self.planner.plan, q_now, option.q)
            if isinstance(result, PlanFailure):
                failures.append(f"{result.reason}: {result.detail}")
                continue
            motion = self.planner.executable(result, self.robot.motion)
            if isinstance(motion, PlanFailure):
                failures.append(f"{motion.reason}: {motion.detail}")
                continue
            self._go(State.EXECUTE)
            self._timer.call("execute", self.robot.execute, motion)
            self._motion_s += result.duration_s
            self._go(State.SETTLE)
            if not self._timer.call("settle", self._settled, option.q):
                return self._skip(view, "arm did not settle at the goal", attempt)
            return self._capture(view, attempt, result.duration_s)
        return self._skip(
            view, "planning failed for every option: " + "; ".join(failures), len(failures)
        )

    def _settled(self, q_goal: np.ndarray) -> bool:
        s = self.settings
        deadline = time.monotonic() + s.settle_timeout_s
        while True:
            if np.max(np.abs(self.robot.joint_positions() - q_goal)) <= s.settle_tolerance_rad:
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(self.settle_poll_s)

    def _capture(self, view: PlannedView, attempts: int, motion_s: float) -> ViewOutcome:
        for k in range(self.settings.capture_retries + 1):
            self._go(State.CAPTURE, f"view {view.index} try {k + 1}")
            try:
                pair = self._timer.call("capture", self.camera.capture)
            except CaptureError as e:
                log.warning("capture of view %d failed: %s", view.index, e)
                continue
            q = self.robot.joint_positions()
            capture = Capture.of(view.index, self.pose_count, q, self._fk(q), pair)
            self._timer.call("store", self.store.write_capture, capture)
            if self.process is not None:
                self._go(State.PROCESS)
                self._timer.call("process", self.process, capture)
            return ViewOutcome(view.index, True, "", attempts, motion_s)
        return self._skip(
            view, f"capture failed {self.settings.capture_retries + 1} times", attempts
        )

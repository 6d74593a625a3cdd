"""The records of a scan plan (`scanner scan --plan-only`): each viewpoint, reachable or not
and why, and the plan as a whole."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Why a viewpoint is not reached. The first three are decided before the tour (the view is
# dropped), the others are the planner's PlanFailure reasons for the move to the view.
UNREACHABLE_REASONS = (
    "no_ik_solution",
    "in_collision",
    "too_few_reachable_directions",
    "start_invalid",
    "goal_invalid",
    "no_path",
    "validation_failed",
)


@dataclass(frozen=True, eq=False)
class PlannedViewpoint:
    """One viewpoint of the plan.

    index: the scan's view index (None for a view dropped before the scan numbers its views).
    order: position in the visiting order, 1 = first (None: never visited).
    X_WC: camera pose (m): where the capture would be taken when reachable, else the pose
    asked for (zero roll); None when not even a direction exists.
    q_rad: the joint configuration the move ends at (None when unreachable).
    reason: "" when reachable, else one of UNREACHABLE_REASONS; detail: for humans.
    motion_s: duration of the time-parameterised move to this view (s).
    number: the view's number in plan.png and in the messages, 1 = first in its hanging: the
    visited views in tour order, then those dropped before the tour.
    """

    index: int | None
    hanging: int
    order: int | None
    direction: np.ndarray | None
    X_WC: np.ndarray | None
    q_rad: np.ndarray | None
    reachable: bool
    reason: str = ""
    detail: str = ""
    motion_s: float = 0.0
    number: int = 0


@dataclass(frozen=True, eq=False)
class ScanPlan:
    viewpoints: tuple[PlannedViewpoint, ...]
    scan_center_m: np.ndarray
    keep_out_radius_m: float
    hangings: int
    extra_views_not_planned: int  # next-best views per hanging: they depend on the captures

    @property
    def robot_time_s(self) -> float:
        """Summed durations of the moves, what the scan reports as robot_motion_s."""
        return float(sum(v.motion_s for v in self.viewpoints))

    @property
    def reachable_count(self) -> int:
        return sum(v.reachable for v in self.viewpoints)

    @property
    def unreachable(self) -> tuple[PlannedViewpoint, ...]:
        return tuple(v for v in self.viewpoints if not v.reachable)

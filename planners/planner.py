"""The planning API the scan calls: reachable views, collision-free time-optimal moves, tours.

    planner = Planner(workcell, X_FC, X_CR, PlannerConfig(cache_dir=...), arm)
    qs = planner.reachable(viewpoint, q_now)          # collision-free IK solutions, best first
    result = planner.plan(q_now, qs[0])               # Trajectory | PlanFailure
    planner.estimate_duration_s(q_a, q_b)             # for ordering tours (planners.tour)

Every Trajectory returned has passed `validation.validate_trajectory` (dense joint steps,
collision with padding, position/velocity/acceleration limits); a plan that fails it is reported
as a PlanFailure, never returned. PlanFailure.reason is one of PLAN_FAILURE_REASONS:
- "start_invalid": the start is outside the joint limits or in collision (within the padding);
- "goal_invalid": the same for the goal (e.g. a goal inside an obstacle);
- "no_path": no collision-free path was found (roadmap, then RRTConnect within query_time_s);
- "validation_failed": paths were found but none survived time parameterisation + validation.
Malformed input (wrong shape, NaN, a viewpoint inside the object) raises ScannerError.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planners.collision import CollisionChecker
from planners.config import PlannerConfig
from planners.ik import Viewpoint, camera_pose, ik_camera, rig_centre_offset
from planners.joint_linear import joint_linear_trajectory
from planners.prm import (
    OmplSpace,
    Roadmap,
    RoadmapGraph,
    build_roadmap,
    cache_key,
    load_roadmap,
    save_roadmap,
    seed_ompl,
    shortcut,
    solve_rrtconnect,
)
from planners.timing import (
    SMOOTH,
    STOP,
    PlanStats,
    Trajectory,
    creep,
    merge_close_waypoints,
    straight_line_time_s,
    time_parameterise,
)
from planners.validation import ValidationReport, validate_trajectory
from reconstruction.common.errors import ScannerError
from robots.arms.arm import Arm
from robots.arms.default import DEFAULT_ARM
from robots.drivers.interfaces import JointTrajectory
from robots.models.workcell import Workcell, keep_out_radius_m

PLAN_FAILURE_REASONS = ("start_invalid", "goal_invalid", "no_path", "validation_failed")


@dataclass(frozen=True)
class PlanFailure:
    """Why no trajectory was returned: reason in PLAN_FAILURE_REASONS, detail for humans."""

    reason: str
    detail: str

    def __post_init__(self) -> None:
        if self.reason not in PLAN_FAILURE_REASONS:
            raise ValueError(f"unknown reason {self.reason!r}; valid: {PLAN_FAILURE_REASONS}")


class Planner:
    """Plans collision-free, time-optimal motions of the arm in one work cell (see module
    docstring). The work cell must have been built with the same arm."""

    def __init__(
        self,
        workcell: Workcell,
        X_FC: np.ndarray,
        X_CR: np.ndarray,
        config: PlannerConfig,
        arm: Arm = DEFAULT_ARM,
    ) -> None:
        self.workcell = workcell
        self.config = config
        self.arm = arm
        self.X_FC = np.array(X_FC, float)
        self.X_MC = rig_centre_offset(np.asarray(X_CR, float))
        self._check_model_matches(workcell, arm)
        self._v = arm.velocity
        self._a = arm.acceleration
        self.checker = CollisionChecker(workcell, config.padding_m, config.edge_step_rad)
        seed_ompl(config.seed)
        self.space = OmplSpace(arm, self.checker)
        self.roadmap_key = cache_key(self._key_parts())
        self.roadmap, self.roadmap_from_cache = self._load_or_build()
        self.graph = RoadmapGraph(self.roadmap, self._v)

    # --- set-up ------------------------------------------------------------------------------

    def _check_model_matches(self, workcell: Workcell, arm: Arm) -> None:
        plant = workcell.plant
        if plant.num_positions() != arm.joint_count:
            raise ScannerError(
                f"planner: the work cell must have the arm ({arm.name}) as its only moving model "
                f"({arm.joint_count} joints), it has {plant.num_positions()} positions"
            )
        lo, hi = plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits()
        if not (np.allclose(lo, arm.lower) and np.allclose(hi, arm.upper)):
            raise ScannerError(
                f"planner: the arm given ({arm.name}) differs from the one in the work cell"
            )

    def _configuration(self, q, name: str) -> np.ndarray:
        q = np.asarray(q, dtype=float) if not isinstance(q, np.ndarray) else q.astype(float)
        n = self.arm.joint_count
        if q.shape != (n,):
            raise ScannerError(f"{name}: expected {n} joint positions (rad), got shape {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ScannerError(f"{name}: joint positions must be finite, got {q.tolist()}")
        return q

    def _key_parts(self) -> dict[str, str]:
        """Everything the roadmap depends on; any change gives another key (a new roadmap)."""
        return {
            "urdf": self.arm.model_text,
            "robot": self.arm.identity,
            "cell": repr(self.workcell.config),
            "collision_geometry": self.checker.fingerprint(),
            "X_FC": np.round(self.X_FC, 12).tobytes().hex(),
            "planner": repr(sorted(self.config.roadmap_parameters().items())),
            "versions": f"drake {_version('drake')}; ompl {_version('ompl')}; "
            f"numpy {np.__version__}; scipy {_version('scipy')}; python {sys.version_info[:2]}",
        }

    def _load_or_build(self) -> tuple[Roadmap, bool]:
        cache_dir = self.config.cache_dir
        if cache_dir is not None:
            cached = load_roadmap(Path(cache_dir), self.roadmap_key, self.arm.joint_count)
            if cached is not None:
                return cached, True
        roadmap = build_roadmap(
            self.space,
            self.config.roadmap_milestones,
            self.config.prm_neighbours,
            self.config.prm_build_time_s,
            self.roadmap_key,
        )
        if cache_dir is not None:
            save_roadmap(Path(cache_dir), roadmap)
        return roadmap, False

    # --- queries -----------------------------------------------------------------------------

    def is_collision_free(self, q) -> bool:
        """Within joint limits and no pair closer than the padding."""
        q = self._configuration(q, "q")
        return self.arm.within_limits(q) and self.checker.is_free(q)

    def estimate_duration_s(self, q_a, q_b) -> float:
        """Fastest straight rest-to-rest move (exact if the straight move is free, a lower bound
        otherwise); microseconds, for ordering tours."""
        q_a, q_b = self._configuration(q_a, "q_a"), self._configuration(q_b, "q_b")
        return float(straight_line_time_s(q_b - q_a, self._v, self._a))

    def reachable(
        self,
        viewpoint: Viewpoint,
        q_current,
        rolls_rad: Sequence[float] | None = None,
    ) -> list[np.ndarray]:
        """Collision-free joint solutions putting the LEFT camera at the viewpoint's pose.

        rolls_rad: camera rolls about the optical axis to try (None: the viewpoint's own roll).
        Ordered by estimated motion time from q_current; empty when nothing is reachable.
        """
        q_current = self._configuration(q_current, "q_current")
        self._check_viewpoint(viewpoint)
        rolls = [viewpoint.roll_rad] if rolls_rad is None else [float(r) for r in rolls_rad]
        if not all(math.isfinite(r) for r in rolls):
            raise ScannerError(f"rolls_rad: must be finite, got {rolls}")
        solutions: list[np.ndarray] = []
        for roll in rolls:
            X_WC = camera_pose(dataclasses.replace(viewpoint, roll_rad=roll), self.X_MC)
            for q in ik_camera(self.arm, X_WC, self.X_FC, q_current):
                # Rolls 2 pi apart (or a symmetric roll list) give the same configuration twice
                # (numpy.allclose's test, on all earlier solutions at once: this runs for
                # thousands of viewpoint candidates).
                if not solutions or not np.any(
                    np.all(np.abs(q - solutions) <= 1e-9 + 1e-5 * np.abs(solutions), axis=1)
                ):
                    solutions.append(q)
        if not solutions:
            return []
        free = self.checker.are_free(solutions)
        solutions = [q for q, ok in zip(solutions, free) if ok]
        if not solutions:
            return []
        times = straight_line_time_s(np.array(solutions) - q_current, self._v, self._a)
        return [solutions[i] for i in np.argsort(times, kind="stable")]

    def _check_viewpoint(self, viewpoint: Viewpoint) -> None:
        p_WM = np.asarray(viewpoint.p_WM, float)
        p_WT = np.asarray(viewpoint.p_WT, float)
        if p_WM.shape != (3,) or p_WT.shape != (3,):
            raise ScannerError("viewpoint: p_WM and p_WT must be 3-vectors (m)")
        if not (np.all(np.isfinite(p_WM)) and np.all(np.isfinite(p_WT))):
            raise ScannerError(f"viewpoint: positions must be finite, got {viewpoint}")
        if not math.isfinite(viewpoint.roll_rad):
            raise ScannerError(f"viewpoint: roll_rad must be finite, got {viewpoint.roll_rad}")
        if np.linalg.norm(p_WT - p_WM) < 1e-6:
            raise ScannerError("viewpoint: the camera and its target coincide")
        if not self.workcell.has_object:
            return
        p_WO = np.asarray(self.workcell.config.object_center_m, float)
        radius = keep_out_radius_m(self.workcell.config)
        distance = float(np.linalg.norm(p_WM - p_WO))
        if distance <= radius:
            raise ScannerError(
                f"viewpoint: the camera at {p_WM.round(4).tolist()} is {distance:.3f} m from the "
                f"object centre, inside the object's keep-out radius {radius:.3f} m"
            )
        if np.dot(p_WO - p_WM, p_WT - p_WM) <= 0:
            raise ScannerError(
                "viewpoint: the object is behind the camera (it looks away from the object)"
            )

    def _configuration_problem(self, q: np.ndarray) -> str | None:
        if not self.arm.within_limits(q):
            lo, hi = self.arm.lower, self.arm.upper
            bad = [i + 1 for i in range(self.arm.joint_count) if not lo[i] <= q[i] <= hi[i]]
            return f"outside the joint limits (joints {bad})"
        if not self.checker.is_free(q):
            return f"in collision, {self.checker.describe(q)}"
        return None

    def plan(self, q_start, q_goal) -> Trajectory | PlanFailure:
        """A validated time-optimal trajectory from q_start to q_goal, or why there is none.

        The roadmap is queried first (the straight move is its cheapest candidate); when it has
        no route, RRTConnect gets query_time_s.
        """
        return self._plan(q_start, q_goal, use_roadmap=True)

    def plan_from_scratch(self, q_start, q_goal) -> Trajectory | PlanFailure:
        """The same pipeline with OMPL RRTConnect instead of the roadmap (for comparison)."""
        return self._plan(q_start, q_goal, use_roadmap=False)

    def _plan(self, q_start, q_goal, use_roadmap: bool) -> Trajectory | PlanFailure:
        q_start = self._configuration(q_start, "q_start")
        q_goal = self._configuration(q_goal, "q_goal")
        problem = self._configuration_problem(q_start)
        if problem:
            return PlanFailure("start_invalid", f"start {problem}")
        problem = self._configuration_problem(q_goal)
        if problem:
            return PlanFailure("goal_invalid", f"goal {problem}")
        if np.abs(q_goal - q_start).max() < self.config.min_move_rad:
            # Too small to time-parameterise (TOPPRA's time grid would collapse): a creep.
            trajectory = creep(q_start, q_goal, self.config.creep_time_s)
            report = self.validate(trajectory, q_start, q_goal)
            if not report.ok:
                return PlanFailure("validation_failed", f"creep: {report.detail}")
            return dataclasses.replace(
                trajectory, stats=PlanStats("hold", "none", 0.0, 0.0, 0.0, 0.0, 2)
            )
        t0 = time.perf_counter()
        waypoints = None
        if use_roadmap:
            waypoints = self.graph.query(
                q_start,
                q_goal,
                self.config.query_neighbours,
                self.checker.edge_free,
                self.config.query_max_edge_checks,
            )
        method = "direct" if waypoints is not None and len(waypoints) == 2 else "roadmap"
        if waypoints is None:
            waypoints = solve_rrtconnect(self.space, q_start, q_goal, self.config.query_time_s)
            method = "rrtconnect"
        search_s = time.perf_counter() - t0
        if waypoints is None:
            where = "the roadmap has no route and " if use_roadmap else ""
            return PlanFailure(
                "no_path",
                f"no collision-free path: {where}RRTConnect found none in "
                f"{self.config.query_time_s} s",
            )
        return self._finish(q_start, q_goal, waypoints, method, search_s)

    def _finish(
        self,
        q_start: np.ndarray,
        q_goal: np.ndarray,
        waypoints: list[np.ndarray],
        method: str,
        search_s: float,
    ) -> Trajectory | PlanFailure:
        """Shortcut, time-parameterise and validate; fall back from smooth to stop corners."""
        t0 = time.perf_counter()
        path = np.array(shortcut(self.space, waypoints, self.config.shortcut_steps))
        path[0], path[-1] = q_start, q_goal
        path = merge_close_waypoints(path, self.config.min_move_rad)
        simplify_s = time.perf_counter() - t0
        timing_s = validation_s = 0.0
        reports: list[str] = []
        modes = (SMOOTH,) if len(path) == 2 else (SMOOTH, STOP)
        for corners in modes:
            gridpoints = self.config.toppra_gridpoints_per_segment * (len(path) - 1)
            fraction = self.config.toppra_limit_fraction
            for _ in range(1 + self.config.toppra_retries):
                t0 = time.perf_counter()
                try:
                    trajectory = time_parameterise(
                        path, self.workcell.plant, self.arm, corners, gridpoints, fraction
                    )
                except RuntimeError as error:  # Drake reports a degenerate path this way
                    trajectory = None
                    reports.append(f"{corners}: TOPPRA failed ({error})")
                t1 = time.perf_counter()
                timing_s += t1 - t0
                if trajectory is None:
                    reports.append(f"{corners}: TOPPRA found no parameterisation")
                    break
                report = self.validate(trajectory, q_start, q_goal)
                validation_s += time.perf_counter() - t1
                if report.ok:
                    stats = PlanStats(
                        method,
                        corners,
                        search_s,
                        simplify_s,
                        timing_s,
                        validation_s,
                        len(waypoints),
                    )
                    return dataclasses.replace(trajectory, stats=stats)
                reports.append(f"{corners}: {report.failed_check} ({report.detail})")
                if report.failed_check not in ("velocity_limit", "acceleration_limit"):
                    break
                # TOPPRA holds the limits at its grid points only: a finer grid and a larger
                # margin bring the peaks between grid points under the true limits.
                gridpoints *= 2
                fraction *= 0.9
        return PlanFailure("validation_failed", "; ".join(reports))

    def executable(self, trajectory: Trajectory, motion: str) -> JointTrajectory | PlanFailure:
        """What a robot driver of kind `motion` (RobotDriver.motion) is given to run: the
        sampled curve, or waypoints whose joint-linear path was validated as such."""
        if motion != "joint_linear":
            return trajectory.to_joint_trajectory()
        c = self.config
        step, tolerance = c.max_joint_step_rad, c.chord_tolerance_rad
        result = joint_linear_trajectory(trajectory, self.checker, self.arm, tolerance, step)
        if isinstance(result, ValidationReport):
            return PlanFailure(
                "validation_failed", f"joint-linear path: {result.failed_check} ({result.detail})"
            )
        return result

    def validate(self, trajectory: Trajectory, q_start, q_goal) -> ValidationReport:
        """The independent dense check every returned trajectory has passed."""
        return validate_trajectory(
            trajectory,
            self._configuration(q_start, "q_start"),
            self._configuration(q_goal, "q_goal"),
            self.checker,
            self.arm,
            self.config.max_joint_step_rad,
            self.config.limit_tolerance,
        )


def _version(distribution: str) -> str:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"

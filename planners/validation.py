"""Dense validation of a time-parameterised trajectory, independent of how it was planned.

The trajectory is sampled in time so finely that no joint moves more than `max_joint_step_rad`
between consecutive samples (the sampling is refined until this is measured to hold), and every
sample is checked for collision (with the planner's padding) and joint position limits. Velocities
and accelerations are evaluated analytically at the samples, and the velocity change between
samples is compared with what the acceleration limit allows, which also catches a velocity jump
hidden between two samples or at a polynomial break. Nothing of the planner (roadmap, OMPL edge
checks, TOPPRA grid) is trusted here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planners.collision import CollisionChecker
from planners.timing import Trajectory
from robots.arms.arm import Arm

# Refinement rounds; each one at least doubles the resolution where it was too coarse.
MAX_REFINEMENTS = 12
# Rounding-level tolerances (not tuning knobs): the curve's own end values vs the exact end
# points, "at rest" at both ends, and the floor on the velocity change allowed between samples.
ENDPOINT_TOLERANCE_RAD = 1e-9
AT_REST_TOLERANCE_RAD_S = 1e-9
VELOCITY_CHANGE_FLOOR_RAD_S = 1e-9


@dataclass(frozen=True)
class ValidationReport:
    """ok, or the first failed check ("endpoints", "resolution", "position_limit",
    "velocity_limit", "acceleration_limit", "collision") with a human-readable detail."""

    ok: bool
    failed_check: str
    detail: str
    samples: int
    max_joint_step_rad: float
    max_velocity_ratio: float
    max_acceleration_ratio: float


def dense_times(trajectory: Trajectory, max_joint_step_rad: float) -> np.ndarray:
    """Sample times with every joint moving at most max_joint_step_rad between neighbours.

    A fine time grid (steps <= half the bound) is thinned greedily: from each kept sample, the
    next one is the farthest fine sample that no joint's accumulated travel |dq| exceeds the
    bound to. Accumulated travel bounds the actual difference, so the bound holds exactly for
    the samples returned, with close to the fewest samples (collision checks are the cost).
    """
    if trajectory.duration_s <= 0.0:
        return np.array([0.0])
    fine = _fine_times(trajectory, max_joint_step_rad / 2)
    q = trajectory.samples(fine)
    travel = np.vstack([np.zeros((1, q.shape[1])), np.cumsum(np.abs(np.diff(q, axis=0)), 0)])
    reach = np.min(
        [
            np.searchsorted(travel[:, i], travel[:, i] + max_joint_step_rad, side="right") - 1
            for i in range(q.shape[1])
        ],
        axis=0,
    )
    keep, k, last = [0], 0, len(fine) - 1
    while k < last:
        # Fine steps are at most half the bound, so reach[k] > k: the walk always advances.
        k = max(int(reach[k]), k + 1)
        keep.append(k)
    return fine[keep]


def _fine_times(trajectory: Trajectory, max_step_rad: float) -> np.ndarray:
    """Times with every joint moving at most max_step_rad between neighbours (refined)."""
    duration = trajectory.duration_s
    travel = np.abs(np.diff(trajectory.path_rad, axis=0)).sum(axis=0).max()
    times = np.linspace(0.0, duration, max(2, math.ceil(travel / max_step_rad) + 1))
    for _ in range(MAX_REFINEMENTS):
        q = trajectory.samples(times)
        steps = np.abs(np.diff(q, axis=0)).max(axis=1)
        coarse = steps > max_step_rad
        if not coarse.any():
            return times
        parts = np.where(coarse, np.ceil(steps / max_step_rad) + 1, 1).astype(int)
        times = np.append(_subdivide(times, parts), times[-1])
    return times


def _subdivide(times: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """Interval k of `times` split into parts[k] equal pieces (start points only)."""
    interval = np.repeat(np.arange(len(parts)), parts)
    first = np.repeat(np.cumsum(parts) - parts, parts)
    fraction = (np.arange(len(interval)) - first) / parts[interval]
    return times[interval] + fraction * np.diff(times)[interval]


def validate_trajectory(
    trajectory: Trajectory,
    q_start: np.ndarray,
    q_goal: np.ndarray,
    checker: CollisionChecker,
    arm: Arm,
    max_joint_step_rad: float,
    limit_tolerance: float,
) -> ValidationReport:
    """Check the whole trajectory; `limit_tolerance` is the relative slack on vel/acc limits."""
    times = dense_times(trajectory, max_joint_step_rad)
    q = trajectory.samples(times)
    qd = trajectory.derivatives(times, 1)
    qdd = trajectory.derivatives(times, 2)
    v, a = arm.velocity, arm.acceleration
    step = float(np.abs(np.diff(q, axis=0)).max()) if len(q) > 1 else 0.0
    v_ratio = float((np.abs(qd) / v).max())
    a_ratio = float((np.abs(qdd) / a).max())

    def report(check: str = "", detail: str = "") -> ValidationReport:
        return ValidationReport(not check, check, detail, len(times), step, v_ratio, a_ratio)

    if not (np.array_equal(q[0], q_start) and np.array_equal(q[-1], q_goal)):
        return report("endpoints", "the trajectory does not start/end at the requested q")
    # samples() returns the exact ends; the curve itself must meet them too (no jump).
    curve_ends = trajectory.q_of_t.vector_values([0.0, trajectory.duration_s]).T
    if np.abs(curve_ends - np.stack([q_start, q_goal])).max() > ENDPOINT_TOLERANCE_RAD:
        return report("endpoints", "the trajectory's curve does not meet its end points")
    if np.abs(qd[[0, -1]]).max() > AT_REST_TOLERANCE_RAD_S:
        return report("endpoints", "the trajectory does not start and end at rest")
    if step > max_joint_step_rad:
        return report("resolution", f"sampling could not reach {max_joint_step_rad} rad steps")
    if np.any(q < arm.lower) or np.any(q > arm.upper):
        return report("position_limit", "a sample leaves the joint limits")
    if v_ratio > 1 + limit_tolerance:
        return report("velocity_limit", f"peak velocity {v_ratio:.3f} x the limit")
    if a_ratio > 1 + limit_tolerance:
        return report("acceleration_limit", f"peak acceleration {a_ratio:.3f} x the limit")
    dv = np.abs(np.diff(qd, axis=0))
    dv_allowed = (1 + limit_tolerance) * a[None, :] * np.diff(times)[
        :, None
    ] + VELOCITY_CHANGE_FLOOR_RAD_S
    if np.any(dv > dv_allowed):
        k = int(np.argmax((dv / dv_allowed).max(axis=1)))
        return report("acceleration_limit", f"velocity jump at t = {times[k]:.4f} s")
    free = checker.are_free(q)
    if not free.all():
        k = int(np.argmin(free))
        return report("collision", f"at t = {times[k]:.4f} s: {checker.describe(q[k])}")
    return report()

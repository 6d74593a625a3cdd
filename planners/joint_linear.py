"""The path a point-to-point controller runs, checked as it will run.

Controllers that take joint waypoints (the Staubli VAL 3 server: one `movej` per point, blending
off) do not follow the planner's time-parameterised curve: they move in a straight line in joint
space from each point to the next and stop there. So the waypoints streamed to them are chosen on
the validated curve such that every chord stays within a tolerance of it, and then the polyline
itself (not the curve) is checked at the dense-validation resolution: collision with the
planner's padding and the joint limits, at samples no joint moves more than max_joint_step_rad
apart. What the controller executes is exactly what was checked.
"""

from __future__ import annotations

import math

import numpy as np

from planners.collision import CollisionChecker
from planners.timing import Trajectory
from planners.validation import ValidationReport, dense_times
from robots.arms.arm import Arm
from robots.drivers.interfaces import JointTrajectory

# Samples per tolerance of joint travel at which chords are checked: the margin between samples
# then costs (1 + sqrt(6)) / 32, about a tenth, of the tolerance for a 6-joint arm.
CHORD_SAMPLES_PER_TOLERANCE = 32


def chord_deviation_rad(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) largest joint deviation of each of the (K, n) points q from the segment a-b."""
    d = b - a
    length2 = float(d @ d)
    s = np.zeros(len(q)) if length2 == 0 else np.clip((q - a) @ d / length2, 0.0, 1.0)
    return np.abs(q - (a + s[:, None] * d)).max(axis=1)


def chord_waypoints(
    trajectory: Trajectory, tolerance_rad: float, max_joint_step_rad: float
) -> tuple[np.ndarray, np.ndarray]:
    """Times (M,) and positions (M, n) on the trajectory, first its start and last its goal,
    such that the curve between consecutive ones stays within tolerance_rad (every joint) of
    their chord: greedily, each chord reaches the farthest sample that keeps it so.

    The deviation is measured at samples, and between two of them the curve can stray further
    from the chord than at either: a point whose joints are within d of a sample's deviates at
    most (1 + sqrt(n)) d more (the point's own offset, and its projection onto the chord
    moving by at most sqrt(n) d). So the samples are taken with every joint moving at most
    tolerance/CHORD_SAMPLES_PER_TOLERANCE between neighbours, and held to the tolerance less
    that bound: the whole curve, not only its samples, stays within the tolerance."""
    step = min(max_joint_step_rad, tolerance_rad / CHORD_SAMPLES_PER_TOLERANCE)
    times = dense_times(trajectory, step)
    q = trajectory.samples(times)
    tolerance_rad -= (1.0 + math.sqrt(q.shape[1])) * step
    keep, i, last = [0], 0, len(q) - 1
    while i < last:
        j = i + 1
        # Doubling then bisection: the deviation grows with the chord's length on a smooth
        # curve; whatever the shape, the chord kept is one that was checked.
        step = 1
        while i + 2 * step <= last and _within(q, i, i + 2 * step, tolerance_rad):
            step *= 2
        lo, hi = i + step, min(i + 2 * step, last)
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if _within(q, i, mid, tolerance_rad):
                lo = mid
            else:
                hi = mid - 1
        j = max(lo, i + 1)
        keep.append(j)
        i = j
    return times[keep], q[keep]


def _within(q: np.ndarray, i: int, j: int, tolerance_rad: float) -> bool:
    if j <= i + 1:
        return True
    return bool(chord_deviation_rad(q[i + 1 : j], q[i], q[j]).max() <= tolerance_rad)


def polyline_samples(waypoints: np.ndarray, max_joint_step_rad: float) -> np.ndarray:
    """Every chord of the polyline cut so that no joint moves more than max_joint_step_rad
    between consecutive samples; the waypoints themselves are samples."""
    out = [waypoints[:1]]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        parts = max(1, math.ceil(float(np.abs(b - a).max()) / max_joint_step_rad))
        s = np.arange(1, parts)[:, None] / parts
        out.append(a + s * (b - a))
        out.append(b[None])  # exactly, not a + 1.0 * (b - a)
    return np.vstack(out)


def validate_polyline(
    waypoints: np.ndarray,
    q_start: np.ndarray,
    q_goal: np.ndarray,
    checker: CollisionChecker,
    arm: Arm,
    max_joint_step_rad: float,
) -> ValidationReport:
    """The dense check of the joint-linear path through `waypoints`: ends, joint limits and
    collision at samples no joint moves more than max_joint_step_rad apart."""
    q = polyline_samples(np.asarray(waypoints, float), max_joint_step_rad)
    step = float(np.abs(np.diff(q, axis=0)).max()) if len(q) > 1 else 0.0

    def report(check: str = "", detail: str = "") -> ValidationReport:
        return ValidationReport(not check, check, detail, len(q), step, 0.0, 0.0)

    if not (np.array_equal(q[0], q_start) and np.array_equal(q[-1], q_goal)):
        return report("endpoints", "the waypoints do not start/end at the requested q")
    if step > max_joint_step_rad * (1 + 1e-9):
        return report("resolution", f"samples {step:.6f} rad apart")
    if np.any(q < arm.lower) or np.any(q > arm.upper):
        return report("position_limit", "a sample leaves the joint limits")
    free = checker.are_free(q)
    if not free.all():
        k = int(np.argmin(free))
        return report("collision", f"at sample {k}: {checker.describe(q[k])}")
    return report()


def joint_linear_trajectory(
    trajectory: Trajectory,
    checker: CollisionChecker,
    arm: Arm,
    tolerance_rad: float,
    max_joint_step_rad: float,
) -> JointTrajectory | ValidationReport:
    """The waypoints a joint-linear controller is given for `trajectory`, checked as the
    controller will run them, or the failed check's report."""
    times, q = chord_waypoints(trajectory, tolerance_rad, max_joint_step_rad)
    report = validate_polyline(
        q, trajectory.q_start, trajectory.q_goal, checker, arm, max_joint_step_rad
    )
    if not report.ok:
        return report
    if len(q) == 1:  # a hold: the controller is given its own position once
        times, q = np.array([0.0, max(trajectory.duration_s, 1e-3)]), np.vstack([q, q])
    return JointTrajectory(times, q, joint_linear=True)

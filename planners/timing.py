"""Time parameterisation of geometric paths (Drake's TOPPRA) and the Trajectory record.

A path is a list of joint-space waypoints whose straight segments were proven collision-free.
It is traversed in one of two ways ("corners"):
- "smooth": a C2 cubic spline q(s) through the waypoints (s = chord length in joint space, rad)
  and one TOPPRA over it; the arm does not stop at waypoints, but the curve leaves the checked
  segments a little between them (the dense validation decides whether that is acceptable);
- "stop": every straight segment gets its own rest-to-rest TOPPRA and the pieces are joined in
  time, so the geometry is exactly the checked polyline and the arm stops at every waypoint.
TOPPRA finds the fastest s(t) under the joint velocity and acceleration limits, scaled by a
margin because it enforces them only at its grid points. A straight move (two waypoints) is the
same in both modes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.multibody.optimization import Toppra
from pydrake.trajectories import (
    CompositeTrajectory,
    PathParameterizedTrajectory,
    PiecewisePolynomial,
)
from pydrake.trajectories import (
    Trajectory as DrakeTrajectory,
)

from robots.arms.arm import Arm
from robots.drivers.interfaces import JointTrajectory

SMOOTH = "smooth"
STOP = "stop"
CORNER_MODES = (SMOOTH, STOP)


def straight_line_time_s(
    dq_rad: np.ndarray, velocity_rad_s: np.ndarray, acceleration_rad_s2: np.ndarray
) -> np.ndarray:
    """Fastest rest-to-rest time along a straight joint-space line, (...,6) -> (...).

    Every joint moves in proportion along a straight line, so the slowest joint's own
    trapezoidal (or triangular) profile sets the time: this is exact for a straight move and a
    lower bound for any path between the same two configurations. Rounded to a microsecond:
    options whose time is set by the same slowest joint tie exactly (camera rolls differing
    only in J6), and unrounded, the last bits of the start joints (float32 from a controller's
    state port) would choose between them, so a scan over the wire would visit other options
    than the same scan in simulation.
    """
    d = np.abs(np.asarray(dq_rad, float))
    v, a = np.asarray(velocity_rad_s, float), np.asarray(acceleration_rad_s2, float)
    triangular = d <= v * v / a
    t = np.where(triangular, 2 * np.sqrt(d / a), d / v + v / a)
    return np.round(np.max(t, axis=-1), 6)


@dataclass(frozen=True)
class PlanStats:
    """Where a plan came from and what each stage cost (s of wall time)."""

    method: str  # "hold" | "direct" | "roadmap" | "rrtconnect"
    corners: str  # "smooth" | "stop" | "none"
    search_s: float
    simplify_s: float
    timing_s: float
    validation_s: float
    waypoints_before_simplify: int

    @property
    def total_s(self) -> float:
        return self.search_s + self.simplify_s + self.timing_s + self.validation_s


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A validated, time-parameterised joint motion q(t), t in [0, duration_s].

    path_rad: (M, 6) geometric waypoints, first the exact start, last the exact goal.
    q_of_t: the Drake trajectory q(t).
    corners: how waypoints are passed, "smooth" or "stop" (see the module docstring), "none"
    for a creep (a move too small for TOPPRA, or a hold).
    """

    path_rad: np.ndarray
    duration_s: float
    q_of_t: DrakeTrajectory
    corners: str
    stats: PlanStats | None = None

    def __post_init__(self) -> None:
        path = np.array(self.path_rad, float)
        path.setflags(write=False)
        object.__setattr__(self, "path_rad", path)

    @property
    def q_start(self) -> np.ndarray:
        return self.path_rad[0]

    @property
    def q_goal(self) -> np.ndarray:
        return self.path_rad[-1]

    def sample(self, t: float) -> np.ndarray:
        """q(t) (rad), clamped to [0, duration]; exactly q_start at 0 and q_goal at the end."""
        return self.samples(np.array([t]))[0]

    def samples(self, times_s: np.ndarray) -> np.ndarray:
        """(K, 6) positions at K times (clamped to the trajectory's span)."""
        t = np.clip(np.asarray(times_s, float), 0.0, self.duration_s)
        if not np.all(np.isfinite(t)):
            raise ValueError("trajectory times must be finite")
        q = self.q_of_t.vector_values(t).T.copy()
        q[t <= 0.0] = self.q_start
        q[t >= self.duration_s] = self.q_goal
        return q

    def derivatives(self, times_s: np.ndarray, order: int) -> np.ndarray:
        """(K, 6) velocities (order 1, rad/s) or accelerations (order 2, rad/s^2)."""
        t = np.clip(np.asarray(times_s, float), 0.0, self.duration_s)
        return self.q_of_t.MakeDerivative(order).vector_values(t).T

    def to_joint_trajectory(self, dt_s: float = 0.01) -> JointTrajectory:
        """Samples every dt_s plus the exact end (at least two samples)."""
        if not dt_s > 0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        times = np.arange(0.0, self.duration_s, dt_s)
        # A last step much shorter than dt_s adds nothing but a near-duplicate sample.
        if self.duration_s - times[-1] < 1e-3 * dt_s and len(times) > 1:
            times = times[:-1]
        times = np.append(times, self.duration_s)
        return JointTrajectory(times, self.samples(times))


def _chord_breaks(path_rad: np.ndarray) -> np.ndarray:
    lengths = np.linalg.norm(np.diff(path_rad, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(lengths)])


def spline_curve(path_rad: np.ndarray) -> PiecewisePolynomial:
    """C2 cubic q(s) through the waypoints, s = chord length (rad), slopes along the end chords.

    Consecutive waypoints must differ. With two waypoints this is exactly the straight line.
    """
    breaks = _chord_breaks(path_rad)
    start_dir = (path_rad[1] - path_rad[0]) / breaks[1]
    end_dir = (path_rad[-1] - path_rad[-2]) / (breaks[-1] - breaks[-2])
    return PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
        breaks, path_rad.T, start_dir, end_dir
    )


def _toppra(curve, plant, arm: Arm, grid: np.ndarray, limit_fraction: float):
    """s(t) of the fastest traversal of curve(s) from rest to rest, or None."""
    toppra = Toppra(curve, plant, grid)
    v = limit_fraction * arm.velocity
    a = limit_fraction * arm.acceleration
    toppra.AddJointVelocityLimit(-v, v)
    toppra.AddJointAccelerationLimit(-a, a)
    return toppra.SolvePathParameterization()


def time_parameterise(
    path_rad: np.ndarray,
    plant,
    arm: Arm,
    corners: str,
    gridpoints_per_segment: int,
    limit_fraction: float,
) -> Trajectory | None:
    """Fastest q(t) along the waypoints under scaled joint limits; None if TOPPRA fails.

    corners "smooth": one TOPPRA over the spline through all waypoints; "stop": one TOPPRA per
    straight segment (rest to rest), the pieces joined in time.
    """
    path_rad = np.asarray(path_rad, float)
    segments = len(path_rad) - 1
    if corners == SMOOTH:
        curve = spline_curve(path_rad)
        breaks = _chord_breaks(path_rad)
        # Waypoints are grid points: that is where the curve bends most.
        grid = np.unique(
            np.concatenate(
                [np.linspace(0.0, breaks[-1], gridpoints_per_segment * segments), breaks]
            )
        )
        s_of_t = _toppra(curve, plant, arm, grid, limit_fraction)
        if s_of_t is None:
            return None
        q_of_t = PathParameterizedTrajectory(curve, s_of_t)
    elif corners == STOP:
        pieces, t_start = [], 0.0
        for q_a, q_b in zip(path_rad[:-1], path_rad[1:]):
            # s in [0, 1] along each segment: break spacing never depends on its length.
            line = PiecewisePolynomial.FirstOrderHold([0.0, 1.0], np.column_stack([q_a, q_b]))
            grid = np.linspace(0.0, 1.0, gridpoints_per_segment)
            s_of_t = _toppra(line, plant, arm, grid, limit_fraction)
            if s_of_t is None:
                return None
            s_of_t.shiftRight(t_start)
            pieces.append(PathParameterizedTrajectory(line, s_of_t))
            t_start = pieces[-1].end_time()
        q_of_t = CompositeTrajectory(pieces)
    else:
        raise ValueError(f"unknown corner mode {corners!r}; valid: {CORNER_MODES}")
    return Trajectory(path_rad, float(q_of_t.end_time()), q_of_t, corners)


def creep(q_start: np.ndarray, q_goal: np.ndarray, duration_s: float) -> Trajectory:
    """A smooth rest-to-rest move over a fixed time, for moves too small to time-parameterise
    (q_goal may equal q_start: a hold). Velocities are |dq| * 1.5 / duration_s."""
    q_start, q_goal = np.asarray(q_start, float), np.asarray(q_goal, float)
    samples = np.column_stack([q_start, q_goal])
    q_of_t = PiecewisePolynomial.CubicHermite([0.0, duration_s], samples, np.zeros_like(samples))
    return Trajectory(np.stack([q_start, q_goal]), float(duration_s), q_of_t, "none")


def merge_close_waypoints(path_rad: np.ndarray, min_segment_rad: float) -> np.ndarray:
    """Drop interior waypoints closer than min_segment_rad (max-norm) to the previous kept one
    or to the goal; start and goal are kept exactly. Spline breaks must be distinct."""
    kept = [path_rad[0]]
    for q in path_rad[1:-1]:
        if np.abs(q - kept[-1]).max() >= min_segment_rad:
            kept.append(q)
    while len(kept) > 1 and np.abs(path_rad[-1] - kept[-1]).max() < min_segment_rad:
        kept.pop()
    return np.array(kept + [path_rad[-1]])

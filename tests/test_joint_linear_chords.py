"""The waypoints a joint-linear controller is given hug the validated curve everywhere, not only
at the samples they were chosen from: curves with sharp bends, whose deviation from a chord
peaks between two samples, are checked at many points per chord."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planners.joint_linear import chord_deviation_rad, chord_waypoints
from planners.timing import Trajectory, spline_curve

TOLERANCE_RAD = math.radians(0.5)
STEP_RAD = math.radians(0.25)


def _bent_path(seed: int) -> Trajectory:
    """A C2 spline through random waypoints 0.05-0.6 rad apart (sharp bends where they are
    close), traversed at unit speed along its chord length."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(size=(6, 6)) * rng.uniform(0.05, 0.6, size=(6, 1))
    path = np.vstack([np.zeros(6), np.cumsum(steps, axis=0)])
    return Trajectory(path, float(spline_curve(path).end_time()), spline_curve(path), "smooth")


@pytest.mark.parametrize("seed", range(12))
def test_every_point_of_the_curve_is_within_the_tolerance_of_its_chord(seed):
    trajectory = _bent_path(seed)
    times, q = chord_waypoints(trajectory, TOLERANCE_RAD, STEP_RAD)
    np.testing.assert_array_equal(q[0], trajectory.q_start)
    np.testing.assert_array_equal(q[-1], trajectory.q_goal)
    assert np.all(np.diff(times) > 0)
    worst = 0.0
    for k in range(len(q) - 1):
        t = np.linspace(times[k], times[k + 1], 400)
        worst = max(worst, chord_deviation_rad(trajectory.samples(t), q[k], q[k + 1]).max())
    assert worst <= TOLERANCE_RAD
    # Not one waypoint per sample: the chords are as long as the tolerance lets them be.
    assert len(q) < len(np.arange(0, trajectory.duration_s, 0.01)) / 3

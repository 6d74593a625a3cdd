"""The true rod of each hanging (the cell's vertical through the object centre, in that hanging's
frame) and a count of model points on it: for tests that check no rod reaches the model."""

from __future__ import annotations

import numpy as np

from reconstruction.common.transforms import invert
from reconstruction.surfaces.fixture import FixtureLine, points_on_fixture

CENTRE = np.array([0.4, 0.0, 1.0])  # the default cell's object centre
ROD_RADIUS_M = 0.004


def rod_line(p=CENTRE, u=(0.0, 0.0, 1.0)) -> FixtureLine:
    return FixtureLine(tuple(map(float, p)), tuple(map(float, u)), ROD_RADIUS_M)


def rod_points(points_W: np.ndarray, truth_vertices_W: np.ndarray, X_WO_hangings) -> int:
    """Points within 10 mm of a hanging's true rod axis and above the object there, in the
    first hanging's frame (where `points_W` and the true surface are)."""
    X0 = np.asarray(X_WO_hangings[0])
    count = 0
    for X in X_WO_hangings:
        T = X0 @ invert(np.asarray(X))  # that hanging's frame -> the first's
        count += points_on_fixture(points_W, truth_vertices_W, rod_line().moved(T))
    return count

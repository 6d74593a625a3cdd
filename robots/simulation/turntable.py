"""The simulated turntable: turns the object about its true axis, reports the angle it was told.

A real turntable's axis is where it was mounted, not where the cell drawing puts it: the true
axis is off the nominal one (the vertical through the disc's centre) by up to 1 mm and tilted by
up to 0.1 deg, drawn from the seed (the software is never told; it calibrates the axis from the
first turns). Its encoder is taken as exact: a stepper turntable repeats to a few hundredths of
a degree, far below what the alignment resolves.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction.common.transforms import rotation_about
from reconstruction.hangings.turntable import Axis, turn_about_axis
from robots.drivers.interfaces import TurntableDriver
from robots.models.turntable import turntable_geometry
from robots.models.workcell import WorkcellConfig

MAX_AXIS_OFFSET_M = 0.001
MAX_AXIS_TILT_RAD = math.radians(0.1)


def true_axis(cell: WorkcellConfig, seed: int) -> Axis:
    """Where the simulated turntable's axis really is (seeded)."""
    rng = np.random.default_rng([seed, 3571])
    g = turntable_geometry(cell)
    azimuth, tilt_azimuth = rng.uniform(0.0, 2 * math.pi, 2)
    offset = rng.uniform(0.0, MAX_AXIS_OFFSET_M)
    tilt = rng.uniform(0.0, MAX_AXIS_TILT_RAD)
    p = np.array(g.p_top_W) + offset * np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    tilt_axis = np.array([math.cos(tilt_azimuth), math.sin(tilt_azimuth), 0.0])
    return Axis(p, rotation_about(tilt_axis, tilt) @ g.u_W)


class SimulatedTurntable(TurntableDriver):
    """Holds the object whose pose at angle 0 is `X_WO_zero`, at `angle_rad` now."""

    def __init__(self, X_WO_zero: np.ndarray, axis: Axis, angle_rad: float = 0.0) -> None:
        self.X_WO_zero, self.axis = np.asarray(X_WO_zero, float), axis
        self._angle_rad = float(angle_rad)

    def rotate_to(self, angle_rad: float) -> None:
        self._angle_rad = float(angle_rad)

    def angle_rad(self) -> float:
        return self._angle_rad

    def X_WO(self) -> np.ndarray:
        """The object's true pose at the angle now."""
        return turn_about_axis(self.axis.p_W, self.axis.u_W, self._angle_rad) @ self.X_WO_zero

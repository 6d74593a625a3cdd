"""Where to hang the object so that an arm sees as much of it as it can: the cell laid out from
the arm's reach.

The viewpoint sphere's radius is the sensor's working distance and is not negotiable; what moves
is the object. Candidate centres lie in front of the arm's base (+x of the world, the side the
cell's table extends to), on a grid of distances from the shoulder and elevations above it, the
distances scaled by the arm's reach plus the radius (the farthest a camera looking at the object
may be from it); each is scored by the share of a coarse viewpoint sphere around it (the
scan's elevation band) that the arm reaches with an IK solution collision-free in the planner's
view of the cell with the object there. The best centre wins (ties: the first in grid order).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from planners.collision import CollisionChecker
from planners.config import PlannerConfig
from planners.ik import Viewpoint, camera_pose, ik_camera, rig_centre_offset
from reconstruction.common.errors import ScannerError
from reconstruction.common.sphere import fibonacci_directions
from robots.arms.arm import Arm
from robots.models.workcell import WorkcellConfig, build_workcell

# Distances of the candidate centres from the shoulder, in units of the arm's reach plus the
# sphere's radius, and their elevations above it (rad). Nearer than about half leaves the arm
# inside the sphere, in the object's way; beyond three quarters little of the sphere is within
# reach. The default arm's measured cell (0.77 of it, 59 deg up: the arm looks at the object
# from below) lies inside this grid.
DISTANCES_OF_REACH = (0.45, 0.6, 0.75)
ELEVATIONS_RAD = (0.0, math.radians(30.0), math.radians(60.0))
# The lowest an object centre may hang above the table top (z = 0): half a metre-class object's
# keep-out sphere and the cameras looking up at it need room.
MIN_CENTER_HEIGHT_M = 0.15


@dataclass(frozen=True)
class ReachSettings:
    """The coarse sphere a candidate centre is scored on: `directions` viewpoint directions in
    the elevation band (rad), each tried at `rolls` camera rolls about the optical axis, and
    the candidate grid (fractions of the arm's reach)."""

    directions: int = 32
    rolls: int = 2
    elevation_min_rad: float = math.radians(-75.0)
    elevation_max_rad: float = math.radians(75.0)
    distances_of_reach: tuple[float, ...] = DISTANCES_OF_REACH
    elevations_rad: tuple[float, ...] = ELEVATIONS_RAD


@dataclass(frozen=True)
class CellReach:
    """The centre chosen (m, world), the share of the coarse sphere the arm reaches there, and
    every candidate centre with its share (the search's evidence)."""

    object_center_m: tuple[float, float, float]
    reach_share: float
    candidates: tuple[tuple[tuple[float, float, float], float], ...]

    def as_dict(self) -> dict:
        return {
            "object_center_m": list(self.object_center_m),
            "reach_share": self.reach_share,
            "candidates": [
                {"object_center_m": list(c), "reach_share": s} for c, s in self.candidates
            ],
        }


def shoulder_and_reach_m(arm: Arm) -> tuple[np.ndarray, float]:
    """The shoulder (the second joint's origin at q = 0, m, world) and an upper bound of how
    far the flange gets from it: the sum of the chain's link lengths after it."""
    chain = arm.chain
    X = chain.X_MF[0] @ chain.X_MF[1] if chain.joint_count > 1 else chain.X_MF[0]
    lengths = np.linalg.norm(chain.X_MF[2:, :3, 3], axis=1)
    return X[:3, 3].copy(), float(lengths.sum())


def candidate_centers(
    arm: Arm, radius_m: float, settings: ReachSettings
) -> list[tuple[float, float, float]]:
    """The grid of centres in front of the shoulder (mm-rounded), none lower than
    MIN_CENTER_HEIGHT_M."""
    shoulder, reach = shoulder_and_reach_m(arm)
    out: list[tuple[float, float, float]] = []
    for elevation in settings.elevations_rad:
        for fraction in settings.distances_of_reach:
            d = fraction * (reach + radius_m)
            p = shoulder + d * np.array([math.cos(elevation), 0.0, math.sin(elevation)])
            centre = (
                round(float(p[0]), 3),
                round(float(p[1]), 3),
                round(max(float(p[2]), MIN_CENTER_HEIGHT_M), 3),
            )
            if centre not in out:
                out.append(centre)
    return out


def sphere_share(
    arm: Arm,
    cell: WorkcellConfig,
    X_FC: np.ndarray,
    X_CR: np.ndarray,
    radius_m: float,
    settings: ReachSettings,
    padding_m: float = PlannerConfig().padding_m,
    presentation: str = "hanging",
) -> float:
    """The share of the coarse sphere of `radius_m` around the cell's object centre from which
    the arm's camera (left optical frame at X_FC, its partner at X_CR) looks at the centre with
    an IK solution collision-free in the planner's view of `cell` (the object held by
    `presentation`'s carrier: the rod, the turntable or the table)."""
    workcell = build_workcell(cell, None, X_FC, X_CR, arm, presentation=presentation)
    checker = CollisionChecker(workcell, padding_m, PlannerConfig().edge_step_rad)
    X_MC = rig_centre_offset(X_CR)
    shoulder, reach = shoulder_and_reach_m(arm)
    centre = np.asarray(cell.object_center_m, float)
    directions = fibonacci_directions(
        settings.directions,
        math.sin(settings.elevation_min_rad),
        math.sin(settings.elevation_max_rad),
    )
    rolls = [2 * math.pi * k / settings.rolls for k in range(settings.rolls)]
    reached = 0
    for direction in directions:
        p_WM = tuple(float(v) for v in centre + radius_m * direction)
        for roll in rolls:
            viewpoint = Viewpoint(p_WM, tuple(float(v) for v in centre), roll)
            X_WC = camera_pose(viewpoint, X_MC)
            if np.linalg.norm((X_WC @ np.linalg.inv(X_FC))[:3, 3] - shoulder) > reach:
                # A flange beyond the chain's length: no solution, and a numerical solver
                # spends longest proving that.
                break
            solutions = ik_camera(arm, X_WC, X_FC, arm.home_q)
            if solutions and checker.are_free(solutions).any():
                reached += 1
                break
    return reached / len(directions)


def best_center(
    arm: Arm,
    cell: WorkcellConfig,
    X_FC: np.ndarray,
    X_CR: np.ndarray,
    radius_m: float,
    settings: ReachSettings = ReachSettings(),
) -> CellReach:
    """The candidate centre whose sphere the arm reaches most of (see the module)."""
    scored = []
    for centre in candidate_centers(arm, radius_m, settings):
        try:
            placed = replace(cell, object_center_m=centre)
        except ScannerError:  # a centre the cell cannot hang (above the rod's top)
            continue
        scored.append((centre, sphere_share(arm, placed, X_FC, X_CR, radius_m, settings)))
    best = max(range(len(scored)), key=lambda i: (scored[i][1], -i))
    return CellReach(scored[best][0], scored[best][1], tuple(scored))

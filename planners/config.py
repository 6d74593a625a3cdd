"""The planner's settings (the `planner:` section): clearance, roadmap, query, timing, validation
and the controller's waypoints. Units are in the names; every field is validated on construction."""

from __future__ import annotations

import math
from dataclasses import dataclass

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class PlannerConfig:
    """Planner settings. Units are in the names; every field is validated on construction."""

    # Clearance kept between the robot (incl. tool) and the cell, and between robot links.
    padding_m: float = positive(0.010)
    # Roadmap: OMPL PRM grows until it has roadmap_milestones vertices or prm_build_time_s.
    roadmap_milestones: int = integer(1000)
    prm_build_time_s: float = positive(90.0)
    prm_neighbours: int = integer(10)
    # Edges are collision-checked with no joint moving more than this between checks.
    edge_step_rad: float = positive(0.5 * _DEG)
    # A query joins start and goal to this many nearest milestones (lazily checked).
    query_neighbours: int = integer(10)
    query_max_edge_checks: int = integer(60)
    # Fallback when the roadmap has no route: OMPL RRTConnect for at most this long.
    query_time_s: float = positive(1.0)
    # OMPL shortcutting: attempts per pass of vertex reduction / shortcutting.
    shortcut_steps: int = integer(6)
    # TOPPRA: grid points per path segment (20 put a straight move within 0.05 % of its
    # optimal time); limits scaled by this fraction because TOPPRA enforces them at grid
    # points only (the validation checks the true limits).
    toppra_gridpoints_per_segment: int = integer(20, minimum=2)
    toppra_limit_fraction: float = 0.95
    # When the validation finds a limit exceeded: retries with twice the grid, 0.9 x the limits.
    toppra_retries: int = integer(2, minimum=0)
    # Dense validation: sample spacing (at most 0.25 deg per joint, so that no obstacle thinner
    # than the padding slips between samples at the arm's reach) and relative slack on the
    # velocity/acceleration limits (numerical noise only).
    max_joint_step_rad: float = positive(0.25 * _DEG)
    limit_tolerance: float = 1e-6
    # A point-to-point controller's waypoints: each straight joint-space chord stays this close
    # to the validated curve (fewer points: faster, the controller stops at each); the chords
    # themselves are then validated densely.
    chord_tolerance_rad: float = positive(0.5 * _DEG)
    # Moves smaller than this (max over joints) are far below encoder resolution: they are
    # made as a smooth creep of creep_time_s instead of through the planner.
    min_move_rad: float = positive(1e-6)
    creep_time_s: float = positive(0.01)
    # Where roadmaps are cached (None: never cached).
    cache_dir: str | None = None
    seed: int = integer(1)  # OMPL rejects a zero seed

    def __post_init__(self) -> None:
        check_fields("planner", self)
        if not 0 < self.toppra_limit_fraction <= 1:
            raise ScannerError("planner.toppra_limit_fraction: must be in (0, 1]")
        if self.edge_step_rad > 0.5 * _DEG + 1e-12:
            raise ScannerError(
                f"planner.edge_step_rad: at most 0.5 deg (0.00873 rad), got {self.edge_step_rad}"
            )
        if self.max_joint_step_rad > 0.25 * _DEG + 1e-12:
            raise ScannerError(
                "planner.max_joint_step_rad: at most 0.25 deg (0.00436 rad), got "
                f"{self.max_joint_step_rad}"
            )
        if not (0 <= self.limit_tolerance < 0.01):
            raise ScannerError("planner.limit_tolerance: must be in [0, 0.01)")
        if self.cache_dir is not None and not self.cache_dir.strip():
            raise ScannerError("planner.cache_dir: expected a folder, or none, got ''")

    def roadmap_parameters(self) -> dict:
        """The fields the roadmap depends on (the cache key), not the query-time ones."""
        names = ("padding_m", "roadmap_milestones", "prm_build_time_s", "prm_neighbours")
        return {n: getattr(self, n) for n in names} | {
            "edge_step_rad": self.edge_step_rad,
            "seed": self.seed,
        }

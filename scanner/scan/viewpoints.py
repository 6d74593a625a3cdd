"""Viewpoints on a sphere around the scan centre, all looking at it, filtered by reachability.

Two distributions:
- "reachable" (default): N directions spread evenly over the part of the sphere the arm can
  actually reach (the RX60 reaches ~10 % of a 0.5 m sphere around an object hung above it):
  a dense Fibonacci lattice of candidates is tested, then N are chosen by farthest-point sampling
  refined by Lloyd iterations on the reachable candidates.
- "sphere": N Fibonacci directions on the whole sphere (within the elevation band); an
  unreachable one is replaced by the nearest unused reachable candidate within
  `replace_within_rad`, else dropped and reported (the SDU report's scheme).
Camera roll about the optical axis is free: every roll candidate is tried and the options are
kept for the planner.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from planners.ik import Viewpoint
from reconstruction.common.errors import ScannerError
from reconstruction.common.sphere import fibonacci_directions
from scanner.configs.views import ViewpointConfig
from scanner.scan.sampling import farthest_point_sample
from scanner.scan_dir.views import PlannedView, ViewOption


@dataclass(frozen=True)
class DroppedView:
    direction: tuple[float, float, float] | None
    reason: str


@dataclass(frozen=True, eq=False)
class ViewPlan:
    views: tuple[PlannedView, ...]
    dropped: tuple[DroppedView, ...]
    reachable_fraction: float
    # Every reachable candidate direction (unit, from the centre): where extra views may go.
    reachable_directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def _band(config: ViewpointConfig, n: int) -> np.ndarray:
    return fibonacci_directions(
        n, math.sin(config.elevation_min_rad), math.sin(config.elevation_max_rad)
    )


def _rolls(config: ViewpointConfig) -> list[float]:
    """Roll candidates, zero first, then alternating +-: the first hit is the most upright."""
    step = 2 * math.pi / config.roll_candidates
    rolls = [0.0]
    for k in range(1, config.roll_candidates):
        r = step * ((k + 1) // 2) * (1 if k % 2 else -1)
        if -math.pi < r <= math.pi:
            rolls.append(r)
    return rolls[: config.roll_candidates]


ReachableFn = Callable[[Viewpoint], list[np.ndarray]]


def _viewpoint(
    center: np.ndarray, direction: np.ndarray, radius_m: float, roll: float
) -> Viewpoint:
    p = center + radius_m * direction
    return Viewpoint(tuple(float(v) for v in p), tuple(float(v) for v in center), float(roll))


def _is_reachable(center, direction, config, reachable: ReachableFn) -> bool:
    return any(
        reachable(_viewpoint(center, direction, config.radius_m, roll)) for roll in _rolls(config)
    )


def _options(
    center, direction, config, reachable: ReachableFn, option_cost: Callable[[np.ndarray], float]
) -> list[ViewOption]:
    """The cheapest `options_per_view` (roll, q) pairs by `option_cost` (e.g. time from home)."""
    options = []
    for roll in _rolls(config):
        for q in reachable(_viewpoint(center, direction, config.radius_m, roll)):
            options.append(ViewOption(roll, q))
    options.sort(key=lambda o: option_cost(o.q))
    return options[: config.options_per_view]


def spread_evenly(points: np.ndarray, n: int, iterations: int) -> list[int]:
    """n indices of unit vectors `points` spread evenly: FPS, then Lloyd steps snapped to points."""
    if n >= len(points):
        return list(range(len(points)))
    mean = points.mean(axis=0)
    chosen = farthest_point_sample(
        n, int(np.argmax(points @ mean)), lambda i: np.linalg.norm(points - points[i], axis=1)
    )
    for _ in range(iterations):
        owner = np.argmax(points @ points[chosen].T, axis=1)
        new = []
        for k in range(len(chosen)):
            cell = points[owner == k]
            if len(cell) == 0:
                new.append(chosen[k])
                continue
            centroid = cell.mean(axis=0)
            scores = points @ centroid
            scores[new] = -np.inf  # keep the indices distinct
            new.append(int(np.argmax(scores)))
        if new == chosen:
            break
        chosen = new
    return chosen


def generate_viewpoints(
    config: ViewpointConfig,
    center_m: Sequence[float],
    reachable: ReachableFn,
    option_cost: Callable[[np.ndarray], float] = lambda q: 0.0,
) -> ViewPlan:
    """Views around `center_m`; `reachable(viewpoint)` returns collision-free IK solutions."""
    center = np.asarray(center_m, float)
    candidates = _band(config, config.candidates)
    ok = np.array([_is_reachable(center, d, config, reachable) for d in candidates])
    fraction = float(ok.mean())
    if not ok.any():
        raise ScannerError(
            f"no viewpoint at radius {config.radius_m} m around {tuple(center.round(3))} is "
            f"reachable and collision-free ({config.candidates} directions x "
            f"{config.roll_candidates} rolls tried); use a radius the arm can reach around this "
            "centre (with the default cell: 0.4-0.55 m) or move the scan centre"
        )
    if ok.sum() < config.count:
        raise ScannerError(
            f"views.count: {config.count} views asked, but only {int(ok.sum())} of "
            f"{config.candidates} directions at radius {config.radius_m} m around "
            f"{tuple(float(v) for v in center.round(3))} are reachable and collision-free "
            f"({100 * fraction:.0f} % of the sphere); ask fewer views, or move the object "
            "(cell.object_center_m; an arm file's scan without it hangs the object where the "
            "arm reaches most), or change views.radius_m"
        )
    reachable_dirs = candidates[ok]
    dropped: list[DroppedView] = []
    if config.distribution == "reachable":
        directions = reachable_dirs[
            spread_evenly(reachable_dirs, config.count, config.lloyd_iterations)
        ]
        if len(directions) < config.count:
            dropped.append(
                DroppedView(
                    None, f"only {len(directions)} reachable directions for {config.count} views"
                )
            )
    else:
        directions, used = [], set()
        for d in _band(config, config.count):
            if _is_reachable(center, d, config, reachable):
                directions.append(d)
                continue
            angles = np.arccos(np.clip(reachable_dirs @ d, -1, 1))
            angles[list(used)] = np.inf
            k = int(np.argmin(angles))
            if angles[k] <= config.replace_within_rad:
                used.add(k)
                directions.append(reachable_dirs[k])
            else:
                dropped.append(
                    DroppedView(
                        tuple(float(v) for v in d), "unreachable and no reachable direction nearby"
                    )
                )
        directions = np.array(directions).reshape(-1, 3)
    views = []
    for d in directions:
        options = _options(center, d, config, reachable, option_cost)
        if not options:
            dropped.append(DroppedView(tuple(float(v) for v in d), "no collision-free IK solution"))
            continue
        best = options[0]
        views.append(
            PlannedView(
                len(views), d, _viewpoint(center, d, config.radius_m, best.roll_rad), tuple(options)
            )
        )
    return ViewPlan(tuple(views), tuple(dropped), fraction, reachable_dirs)


def planned_view(
    index: int,
    center_m: Sequence[float],
    direction: np.ndarray,
    config: ViewpointConfig,
    reachable: ReachableFn,
    option_cost: Callable[[np.ndarray], float] = lambda q: 0.0,
) -> PlannedView | None:
    """One more view in `direction` (e.g. a next-best view), or None when no configuration
    reaches it."""
    center = np.asarray(center_m, float)
    options = _options(center, direction, config, reachable, option_cost)
    if not options:
        return None
    viewpoint = _viewpoint(center, direction, config.radius_m, options[0].roll_rad)
    return PlannedView(index, np.asarray(direction, float), viewpoint, tuple(options))

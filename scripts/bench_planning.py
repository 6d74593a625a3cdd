"""Benchmark of the planning layer on the default work cell and object.

Prints ONE JSON line. Queries are pairs of reachable look-at configurations for viewpoints on a
0.5 m sphere around the object centre (fixed seed): from a random IK solution of one viewpoint to
the solution of another viewpoint that is fastest to reach from there, as the scan moves.
Timing is what the scan pays per move:
- median_query_ms / p95_query_ms: the whole `Planner.plan` (roadmap query, OMPL shortcutting,
  TOPPRA, dense validation); median_search_ms: the roadmap query alone;
- rrtconnect_*: the same pairs through the same pipeline with OMPL RRTConnect from scratch in
  place of the roadmap (rrtconnect_median_search_ms: RRTConnect's solve alone);
- collisions_in_dense_recheck: returned trajectories that collide when re-sampled at <= 0.25 deg
  joint steps against a separately built cell and checker (must be 0);
- ik_per_s: look-at camera poses solved per second by `Planner.reachable` (all IK branches,
  verified by FK, collision-filtered); ik_max_*_error: worst pose error of the solutions returned
  against Drake's own forward kinematics.
The roadmap is built into a fresh temporary cache (roadmap_build_s) and loaded back
(roadmap_load_s) to show the cache.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time

import numpy as np

from planners.collision import CollisionChecker
from planners.config import PlannerConfig
from planners.ik import Viewpoint, camera_pose, rig_centre_offset
from planners.planner import Planner
from planners.timing import Trajectory
from planners.validation import dense_times
from reconstruction.common.sphere import fibonacci_directions
from reconstruction.stereo.camera_model import default_stereo_camera
from robots.models import camera_tool
from robots.models.kinematics import Kinematics
from robots.models.workcell import WorkcellConfig, build_workcell
from robots.simulation.cell import HOME_Q

RADIUS_M = 0.5
ROLLS_RAD = (-math.pi / 6, 0.0, math.pi / 6)


def reachable_views(planner: Planner, directions: np.ndarray):
    """(viewpoint configurations per reachable view, poses solved per second, worst IK error)."""
    c = np.array(planner.workcell.config.object_center_m)
    kin = Kinematics(planner.arm)
    X_MC = rig_centre_offset(default_stereo_camera().X_CR)
    views, solved, elapsed = [], 0, 0.0
    worst_p, worst_r = 0.0, 0.0
    for d in directions:
        vp = Viewpoint(tuple(c + RADIUS_M * d), tuple(c), 0.0)
        start = time.perf_counter()
        qs = planner.reachable(vp, HOME_Q, ROLLS_RAD)
        elapsed += time.perf_counter() - start
        solved += len(ROLLS_RAD)
        for q in qs:
            X_WC = kin.X_WC(q, planner.X_FC)
            # The roll of each solution is unknown here: compare with the closest roll's pose.
            errors = []
            for roll in ROLLS_RAD:
                X_target = camera_pose(Viewpoint(vp.p_WM, vp.p_WT, roll), X_MC)
                dp = np.linalg.norm(X_WC[:3, 3] - X_target[:3, 3])
                cos = (np.trace(X_WC[:3, :3].T @ X_target[:3, :3]) - 1) / 2
                errors.append((dp, math.degrees(math.acos(min(1.0, max(-1.0, cos))))))
            dp, dr = min(errors, key=lambda e: e[0] + e[1])
            worst_p, worst_r = max(worst_p, dp), max(worst_r, dr)
        if qs:
            views.append(qs)
    return views, solved / elapsed, worst_p, worst_r


def query_pairs(views, count: int, rng: np.random.Generator, planner: Planner):
    """Moves the scan makes: from any solution of one view to the solution of another view
    that `reachable` ranks first from there (the fastest to reach)."""
    pairs = []
    while len(pairs) < count:
        a, b = rng.choice(len(views), size=2, replace=False)
        qa = views[a][rng.integers(len(views[a]))]
        qb = min(views[b], key=lambda q: planner.estimate_duration_s(qa, q))
        pairs.append((qa, qb))
    return pairs


def recheck_collisions(trajectories: list[Trajectory], checker: CollisionChecker, step_rad: float):
    """Trajectories with any colliding sample, on an independently built checker."""
    bad = 0
    for trajectory in trajectories:
        q = trajectory.samples(dense_times(trajectory, step_rad))
        if not checker.are_free(q).all():
            bad += 1
    return bad


def run(pairs, plan) -> dict:
    times_ms, search_ms, results = [], [], []
    for qa, qb in pairs:
        start = time.perf_counter()
        result = plan(qa, qb)
        times_ms.append(1e3 * (time.perf_counter() - start))
        results.append(result)
        if isinstance(result, Trajectory):
            search_ms.append(1e3 * result.stats.search_s)
    trajectories = [r for r in results if isinstance(r, Trajectory)]
    methods = [t.stats.method for t in trajectories]
    return {
        "times_ms": np.array(times_ms),
        "search_ms": np.array(search_ms) if search_ms else np.array([np.nan]),
        "trajectories": trajectories,
        "results": results,
        "success_rate": len(trajectories) / len(pairs),
        "methods": {m: methods.count(m) / len(pairs) for m in sorted(set(methods))},
        "failures": sorted({r.reason for r in results if not isinstance(r, Trajectory)}),
    }


def _median(values: np.ndarray) -> float | None:
    return round(float(np.median(values)), 2) if len(values) else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small roadmap and query set")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    wall = time.perf_counter()
    stereo = default_stereo_camera()
    X_FC = camera_tool.nominal_X_FC(stereo.baseline_m)
    cell = WorkcellConfig()
    n_pairs, n_directions = (40, 300) if args.quick else (200, 1000)
    with tempfile.TemporaryDirectory() as cache:
        base = PlannerConfig(cache_dir=cache, seed=args.seed)
        config = (
            PlannerConfig(
                cache_dir=cache, seed=args.seed, roadmap_milestones=300, prm_build_time_s=20.0
            )
            if args.quick
            else base
        )
        planner = Planner(build_workcell(cell, None, X_FC, stereo.X_CR), X_FC, stereo.X_CR, config)
        start = time.perf_counter()
        loaded = Planner(build_workcell(cell, None, X_FC, stereo.X_CR), X_FC, stereo.X_CR, config)
        load_s = time.perf_counter() - start
        assert loaded.roadmap_from_cache and not planner.roadmap_from_cache
    views, ik_per_s, ik_p, ik_r = reachable_views(planner, fibonacci_directions(n_directions))
    pairs = query_pairs(views, n_pairs, np.random.default_rng(args.seed), planner)
    prm = run(pairs, planner.plan)
    rrt = run(pairs, planner.plan_from_scratch)
    independent = CollisionChecker(
        build_workcell(cell, None, X_FC, stereo.X_CR), config.padding_m, config.edge_step_rad
    )
    collisions = recheck_collisions(
        prm["trajectories"] + rrt["trajectories"], independent, config.max_joint_step_rad
    )
    # The pairs the roadmap routed (the straight move was blocked), timed by both planners.
    routed = [
        i
        for i, r in enumerate(prm["results"])
        if isinstance(r, Trajectory) and r.stats.method != "direct"
    ]
    out = {
        "quick": args.quick,
        "roadmap_build_s": round(planner.roadmap.build_s, 2),
        "roadmap_milestones": len(planner.roadmap.vertices_rad),
        "roadmap_edges": len(planner.roadmap.edges),
        "roadmap_load_s": round(load_s, 3),
        "reachable_viewpoints": len(views),
        "viewpoints_tried": n_directions,
        "queries": len(pairs),
        "success_rate": round(prm["success_rate"], 4),
        "median_query_ms": round(float(np.median(prm["times_ms"])), 2),
        "p95_query_ms": round(float(np.percentile(prm["times_ms"], 95)), 2),
        "median_search_ms": round(float(np.nanmedian(prm["search_ms"])), 2),
        "p95_search_ms": round(float(np.nanpercentile(prm["search_ms"], 95)), 2),
        "route_kinds": {k: round(v, 3) for k, v in prm["methods"].items()},
        "routed_queries": len(routed),
        "median_routed_query_ms": _median(prm["times_ms"][routed]),
        "rrtconnect_median_routed_query_ms": _median(rrt["times_ms"][routed]),
        "failure_reasons": prm["failures"],
        "collisions_in_dense_recheck": collisions,
        "mean_trajectory_s": round(float(np.mean([t.duration_s for t in prm["trajectories"]])), 3),
        "ik_per_s": round(ik_per_s, 1),
        "ik_max_position_error_mm": float(f"{1e3 * ik_p:.2g}"),
        "ik_max_rotation_error_deg": float(f"{ik_r:.2g}"),
        "rrtconnect_median_query_ms": round(float(np.median(rrt["times_ms"])), 2),
        "rrtconnect_p95_query_ms": round(float(np.percentile(rrt["times_ms"], 95)), 2),
        "rrtconnect_median_search_ms": round(float(np.nanmedian(rrt["search_ms"])), 2),
        "rrtconnect_success_rate": round(rrt["success_rate"], 4),
        "rrtconnect_mean_trajectory_s": round(
            float(np.mean([t.duration_s for t in rrt["trajectories"]])), 3
        )
        if rrt["trajectories"]
        else None,
        "wall_s": round(time.perf_counter() - wall, 1),
        # Other work on the machine slows every timing above; this says how busy it was.
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()

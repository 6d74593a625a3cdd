"""Benchmark: a default simulated scan (24 views, default resolution, fixed seed).

Prints one JSON line: wall_s, after_last_capture_s (the last capture stored -> the model's
files written: what a user of a real cell waits for once the robot stops; from code that does
not report it, the reconstruction stage's wall time, which omits the wait for the last views'
per-view work), after_last_capture_cpu_s, stage_s, robot_motion_s, robot_motion_s_naive_order
(the same views visited in generation order, planned with the same planner), peak_rss_mb (this
process), peak_rss_child_mb (the largest child process: the Poisson solver), views_captured;
cpu_s (CPU seconds the scan used, the Poisson solver's included), cores, and cpu_bound_wall_s =
cpu_s / cores: the wall time this scan cannot go below on this machine without removing
computation, however well its stages overlap; chamfer_observed_mm of the model against the
simulator's truth. --keep DIR keeps the scan directory there (to time surfaces on its fused
cloud, or to reconstruct it again).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
from pathlib import Path

from planners.planner import Trajectory
from reconstruction.common.memory import keep_freed_memory
from reconstruction.common.stage_timer import cpu_seconds
from scanner.configs.scan import ScanConfig, with_overrides
from scanner.scan.run import run_scan
from scanner.scan.world import setup_world
from scanner.scan_dir.manifest import open_scan


def naive_order_motion_s(config: ScanConfig, scan_dir: Path) -> float:
    """Sum of planned trajectory durations visiting the scan's views in generation order."""
    world = setup_world(config)
    planner = world.planner
    views = open_scan(scan_dir).views
    q = world.robot.joint_positions()
    total = 0.0
    for view in sorted(views, key=lambda v: v.index):
        for option in view.options:
            result = planner.plan(q, option.q)
            if isinstance(result, Trajectory):
                total += result.duration_s
                q = option.q
                break
    return total


def main() -> None:
    keep_freed_memory()  # as the command line does
    parser = argparse.ArgumentParser()
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--object", default="vase")
    parser.add_argument(
        "--hangings",
        type=lambda text: text if text == "auto" else int(text),
        default=1,
        help="passes over the object, re-hung between them (default 1), or 'auto' (the "
        "product's default: more while the model is not complete)",
    )
    parser.add_argument(
        "--keep", type=Path, help="keep the scan directory here (default: a removed temporary one)"
    )
    args = parser.parse_args()
    config = with_overrides(
        ScanConfig(), object_spec=args.object, views=args.views, seed=0, hangings=args.hangings
    )
    with tempfile.TemporaryDirectory() as tmp:
        cpu_start = cpu_seconds()
        result = run_scan(config, args.keep or Path(tmp) / "scan")
        cpu_s = cpu_seconds() - cpu_start
        naive = naive_order_motion_s(config, result.scan_dir)
    r = result.report
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    # The Poisson solve runs in a child process: its peak is not in this process's.
    child_peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    cores = len(os.sched_getaffinity(0))
    print(
        json.dumps(
            {
                "wall_s": round(r["wall_s"], 2),
                "after_last_capture_s": round(
                    r.get("after_last_capture_s", r["stage_s"].get("reconstruction", 0.0)), 2
                ),
                "after_last_capture_cpu_s": round(r.get("after_last_capture_cpu_s", -1.0), 1),
                "stage_s": {k: round(v, 2) for k, v in r["stage_s"].items()},
                "reconstruction_stage_s": {
                    k: round(v, 2) for k, v in r.get("reconstruction_stage_s", {}).items()
                },
                "robot_motion_s": round(r["robot_motion_s"], 3),
                "robot_motion_s_naive_order": round(naive, 3),
                "motion_saving": round(1 - r["robot_motion_s"] / naive, 3) if naive else None,
                "processing_s": round(r.get("processing_s", 0.0), 2),
                "processing_hidden_s": round(r.get("processing_hidden_s", 0.0), 2),
                "peak_rss_mb": round(peak_mb, 1),
                "peak_rss_child_mb": round(child_peak_mb, 1),
                "hangings": args.hangings,
                "pairs_registered_while_scanning": r.get("pairs_registered_while_scanning"),
                "last_capture_to_results_s": round(r.get("last_capture_to_results_s", -1.0), 2),
                "views_captured": r["views_captured"],
                "chamfer_observed_mm": r.get("chamfer_observed_mm"),
                "views_planned": r["views_planned"],
                "cpu_s": round(cpu_s, 1),
                "cores": cores,
                "cpu_bound_wall_s": round(cpu_s / cores, 1),
            }
        )
    )


if __name__ == "__main__":
    main()

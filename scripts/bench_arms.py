"""Benchmark: whole-object scans with every arm the product ships.

The built-in vase and the bunny of the benchmark meshes (0.2 m), seed 0, `--hangings auto`,
with the RX60 (its measured cell) and the UR5e and iiwa 14 of their arm files (each cell laid
out from the arm's reach at the views' radius, scanner/scan/layout.py). Each case is
bench_complete.py's whole-object scan (`_case`), so the figures are the same: whole-object
Chamfer, completeness at 2 mm, alignment. Per case also: planning success (views captured of
those planned), the share of the view sphere the arm reaches (`reachable_fraction`), the robot's
motion time and the object centre used.

The arms solved numerically (UR5e, iiwa) answer an IK request in 0.1-1 s where the RX60's closed
form takes microseconds: their views are chosen from `NUMERIC_VIEW_CANDIDATES` directions at
`NUMERIC_ROLLS` rolls rather than the default 600 at 12, or planning alone would take hours.

Prints one JSON line: per arm the worst completeness and whole Chamfer, the goal (every arm
complete, >= 0.97 at 2 mm, with whole Chamfer <= 0.2 mm) and one record per case.
`--objects` / `--arms` run a subset (e.g. `--objects vase` first: the bunny needs the benchmark
meshes); `--jobs N` runs N cases side by side.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace
from pathlib import Path

from bench_complete import FILES, _case
from benchmark_data import MESHES, require

from reconstruction.common.errors import ScannerError
from scanner.configs.scan import ScanConfig, with_overrides
from scanner.scan_dir.manifest import open_scan

ROOT = Path(__file__).resolve().parents[1]
ARMS = {
    "rx60": "rx60",
    "ur5e": str(ROOT / "scanner" / "configs" / "arms" / "ur5e.yaml"),
    "iiwa14": str(ROOT / "scanner" / "configs" / "arms" / "iiwa14.yaml"),
}
NUMERIC_VIEW_CANDIDATES = 150
NUMERIC_ROLLS = 4
COMPLETENESS_GOAL = 0.97
CHAMFER_GOAL_MM = 0.2
EXTRA_KEYS = ("views_planned", "views_captured", "reachable_fraction", "robot_motion_s")


def base_config(arm: str) -> ScanConfig:
    """The default scan on `arm`; a numerically solved arm chooses among fewer view candidates."""
    config = with_overrides(ScanConfig(), robot=ARMS[arm])
    if arm == "rx60":
        return config
    views = replace(config.views, candidates=NUMERIC_VIEW_CANDIDATES, roll_candidates=NUMERIC_ROLLS)
    return replace(config, views=views)


def arm_case(arm: str, name: str, seed: int, out: Path) -> dict:
    try:
        record = {"arm": arm, **_case(name, seed, out, "auto", "instructed", base_config(arm))}
    except ScannerError as e:  # refused before moving (too little of the sphere in reach)
        return {"arm": arm, "object": name, "seed": seed, "error": str(e)}
    report_path = out / "results" / "report.json"
    if report_path.is_file():
        report = json.loads(report_path.read_text())
        record.update({k: report[k] for k in EXTRA_KEYS if k in report})
        record["planning_success"] = round(
            report.get("views_captured", 0) / max(report.get("views_planned", 1), 1), 4
        )
        record["object_center_m"] = list(open_scan(out).config.cell.object_center_m)
    return record


def _summary(cases: list[dict]) -> dict:
    out = {}
    for arm in dict.fromkeys(c["arm"] for c in cases):
        mine = [c for c in cases if c["arm"] == arm]
        completeness = min(c.get("completeness_2mm", 0.0) for c in mine)
        chamfer = max(c.get("chamfer_mm", 99.0) for c in mine)
        out[arm] = {
            "min_completeness_2mm": completeness,
            "max_chamfer_whole_mm": chamfer,
            "min_reachable_fraction": min(c.get("reachable_fraction", 0.0) for c in mine),
            "goal_met": completeness >= COMPLETENESS_GOAL and chamfer <= CHAMFER_GOAL_MM,
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--objects", default="vase,bunny")
    parser.add_argument("--arms", default=",".join(ARMS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1, help="cases run side by side")
    args = parser.parse_args()
    objects = args.objects.split(",")
    if any(name in FILES for name in objects):
        require(MESHES, "bench_arms")
    with tempfile.TemporaryDirectory() as tmp:
        work = [
            (arm, name, args.seed, Path(tmp) / f"{arm}-{name}")
            for arm in args.arms.split(",")
            for name in objects
        ]
        # Each case in its own process: a scan is one core's work for most of its time.
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            futures = [pool.submit(arm_case, *w) for w in work]
            for future in as_completed(futures):
                print(json.dumps(future.result()), file=sys.stderr, flush=True)
        cases = [f.result() for f in futures]
    per_arm = _summary(cases)
    out = {
        "objects": objects,
        "seed": args.seed,
        "goal": f"completeness_2mm >= {COMPLETENESS_GOAL}, whole Chamfer <= {CHAMFER_GOAL_MM} mm",
        "all_goals_met": all(a["goal_met"] for a in per_arm.values()),
        "arms": per_arm,
        "cases": cases,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()

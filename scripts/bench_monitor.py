"""Benchmark: the cell monitor over three simulated 24-view scans of the vase (capture only):
one without an intruder, two with two intrusions each (different times and paths), plus the
RBF surface against Poisson on the bunny (scripts/bench_rbf.py, run as a child process).

Prints one JSON line: `frames`, `fps_processed` (all frames over the monitor's processing time:
masks, detector, tracker; the simulator's rendering stands for the camera and is not counted),
`intrusions`, `detected`, `detection_latency_ms_max`, `false_alarms`,
`captures_during_intrusion`, `ee_tracking_rms_mm`, `ee_tracking_max_mm`,
`ee_velocity_rms_mm_s` (over the frames where the arm moved), `rbf` (bench_rbf's line), and
`scans` (one record per scan).
Targets: every intrusion detected within 200 ms, 0 false alarms, 0 captures while the cell is
not clear, tracking RMS <= 3 mm; RBF within 1.5x Poisson's observed Chamfer, in <= 60 s.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from scanner.configs.scan import ScanConfig, with_overrides
from scanner.scan.run import run_scan

# (error-model seed, intruder start times s, intruder path seed) per scan.
CASES = ((0, (), 0), (1, (3.0, 10.0), 1), (2, (5.0, 12.5), 2))


def _scan(root: Path, seed: int, intruders: tuple[float, ...], path_seed: int) -> dict:
    config = with_overrides(
        ScanConfig(), seed=seed, monitor=True, intruder_start_s=intruders, hangings=1
    )
    config = replace(
        config, reconstruct=False, monitor=replace(config.monitor, intruder_seed=path_seed)
    )
    start = time.perf_counter()
    result = run_scan(config, root / f"scan-{seed}")
    report = result.report
    m = report["monitor"]
    return {
        "seed": seed,
        "intruder_start_s": list(intruders),
        "views_captured": report["views_captured"],
        "wall_s": round(time.perf_counter() - start, 1),
        **{k: v for k, v in m.items() if k not in ("events", "intruders")},
        "events": [f"{e['t_s']:.2f} {e['kind']}" for e in m["events"]],
    }


def _combined_rms(scans: list[dict], key: str) -> float | None:
    rows = [(s[key], s["ee_tracked_frames"]) for s in scans if s.get(key) is not None]
    if not rows:
        return None
    return math.sqrt(sum(v * v * n for v, n in rows) / sum(n for _, n in rows))


def _rbf(scan_root: Path | None) -> dict | None:
    script = Path(__file__).with_name("bench_rbf.py")
    args = [sys.executable, str(script)]
    if scan_root is not None:
        args += ["--scan-root", str(scan_root)]
    run = subprocess.run(args, capture_output=True, text=True)
    lines = [line for line in run.stdout.splitlines() if line.startswith("{")]
    return json.loads(lines[-1]) if lines else {"skipped": run.stdout.strip() or run.stderr}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scan-root", type=Path, default=None, help="bunny scan for the RBF part")
    parser.add_argument("--no-rbf", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scans = [_scan(Path(tmp), *case) for case in CASES]
    frames = sum(s["frames"] for s in scans)
    processing = sum(s["frames"] / s["fps_processed"] for s in scans)
    latencies = [s["detection_latency_ms_max"] for s in scans if s["detection_latency_ms_max"]]
    out = {
        "frames": frames,
        "fps_processed": round(frames / processing, 1),
        "intrusions": sum(s["intrusions"] for s in scans),
        "detected": sum(s["detected"] for s in scans),
        "detection_latency_ms_max": round(max(latencies), 1) if latencies else 0.0,
        "false_alarms": sum(s["false_alarms"] for s in scans),
        "captures_during_intrusion": sum(s["captures_during_intrusion"] for s in scans),
        "ee_tracking_rms_mm": _combined_rms(scans, "ee_tracking_rms_mm"),
        "ee_tracking_max_mm": max(s.get("ee_tracking_max_mm") or 0.0 for s in scans),
        "ee_velocity_rms_mm_s": _combined_rms(scans, "ee_velocity_rms_mm_s"),
        "rbf": None if args.no_rbf else _rbf(args.scan_root),
        "scans": scans,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()

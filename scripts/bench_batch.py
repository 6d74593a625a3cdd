"""Benchmark: reconstruct 4 saved scans one after the other, then as a Ray batch, in one run.

Scans (or reuses, with --scan-root holding scan0..scan3) four 24-view vase scans with seeds
0-3, capture only. Prints one JSON line: sequential_s, ray_s (Ray's start included), speedup,
identical (every Poisson and TSDF mesh and the metrics of the batch equal the sequential ones),
workers.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import open3d as o3d

from reconstruction.common.memory import keep_freed_memory
from scanner.configs.scan import ScanConfig, with_overrides
from scanner.reconstruct.batch import run_batch
from scanner.reconstruct.command import ReconstructOptions, reconstruct_one
from scanner.scan.run import run_scan

METRICS = ("chamfer_mm", "chamfer_observed_mm", "handeye_error_mm", "handeye_error_deg")


def _scans(root: Path, count: int, views: int) -> list[Path]:
    dirs = []
    for seed in range(count):
        scan_dir = root / f"scan{seed}"
        if not (scan_dir / "scan.yaml").is_file():
            config = replace(
                with_overrides(ScanConfig(), views=views, seed=seed, hangings=1), reconstruct=False
            )
            run_scan(config, scan_dir)
        dirs.append(scan_dir)
    return dirs


def _same(a: Path, b: Path, report_a: dict, report_b: dict) -> bool:
    for name in ("mesh_poisson.ply", "mesh_tsdf.ply"):
        ma = o3d.io.read_triangle_mesh(str(a / name))
        mb = o3d.io.read_triangle_mesh(str(b / name))
        if not (
            np.array_equal(np.asarray(ma.vertices), np.asarray(mb.vertices))
            and np.array_equal(np.asarray(ma.triangles), np.asarray(mb.triangles))
        ):
            return False
    return all(report_a[k] == report_b[k] for k in METRICS)


def main() -> None:
    keep_freed_memory()  # as the command line does
    parser = argparse.ArgumentParser()
    parser.add_argument("--scan-root", type=Path, default=None, help="reuse/keep scans here")
    parser.add_argument("--scans", type=int, default=4)
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        dirs = _scans(args.scan_root or Path(tmp) / "scans", args.scans, args.views)
        t0 = time.perf_counter()
        sequential = [
            reconstruct_one(d, ReconstructOptions(out=Path(tmp) / "one-by-one" / d.name))
            for d in dirs
        ]
        sequential_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        # Into a free SCAN_DIR/results[-N] of each scan, as `scanner reconstruct A B C D` does.
        batch = run_batch(dirs, reconstruct_one, ReconstructOptions(), args.workers, None, _line)
        ray_s = time.perf_counter() - t0
        identical = all(
            o.ok and _same(s.results_dir, o.results_dir, s.report, o.report)
            for s, o in zip(sequential, batch)
        )
    print(
        json.dumps(
            {
                "scans": len(dirs),
                "workers": args.workers,
                "sequential_s": round(sequential_s, 1),
                "ray_s": round(ray_s, 1),
                "speedup": round(sequential_s / ray_s, 3),
                "identical": identical,
            }
        )
    )


def _line(outcome) -> None:
    print(f"{outcome.scan_dir}: {'ok' if outcome.ok else 'FAILED ' + outcome.error}", flush=True)


if __name__ == "__main__":
    main()

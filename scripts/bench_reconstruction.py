"""Benchmark: reconstruct 24-view simulated scans of the benchmark meshes (benchmark_data.py).

Scans (or reuses, with --scan-root) each object (largest extent 0.2 m, default error model:
3 mm / 1 deg hand-eye error) and prints one JSON line. The Stanford bunny is reconstructed three
ways: `pose_only` (nominal X_FC, no ICP), `icp` (ICP + pose graph) and `corrected` (plus hand-eye
correction), with `reconstruct_s` of the corrected run (stereo included) and its CPU seconds
`reconstruct_cpu_s` (divided by `cores`: `reconstruct_cpu_bound_s`, the wall time that run cannot
go below on this machine without removing computation); the other objects of --objects (spot,
fandisk, teapot) get the corrected variant under their own key.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from benchmark_data import MESHES, add_scan_options, mesh_scan, require

from reconstruction.common.memory import keep_freed_memory
from reconstruction.common.stage_timer import cpu_seconds
from reconstruction.config import VARIANTS, variant_config
from reconstruction.evaluation.metrics import HANDEYE_ERROR_KEYS, SURFACE_METRIC_KEYS
from scanner.configs.scan import ProcessingConfig
from scanner.reconstruct.stages import run_reconstruct
from scanner.scan_dir.captures import CaptureStore

OBJECTS = {
    "bunny": "stanford-bunny.obj",
    "spot": "spot.obj",
    "fandisk": "fandisk.obj",
    "teapot": "teapot.obj",
}
KEYS = (*SURFACE_METRIC_KEYS, *HANDEYE_ERROR_KEYS)


def _variants(scan_dir: Path, names, out: Path) -> dict:
    result: dict = {"views": len(CaptureStore.open(scan_dir).captured_indices())}
    base = ProcessingConfig()
    for name in names:
        rec = variant_config(base.reconstruction, name)
        cpu_start = cpu_seconds()
        run = run_reconstruct(scan_dir, replace(base, reconstruction=rec), out / name)
        cpu_s = cpu_seconds() - cpu_start
        result[name] = {k: round(run.report[k], 4) for k in KEYS if k in run.report}
        if name == "corrected":
            result["reconstruct_s"] = round(run.report["reconstruct_s"], 2)
            cores = len(os.sched_getaffinity(0))
            result["reconstruct_cpu_s"] = round(cpu_s, 1)
            result["cores"] = cores
            result["reconstruct_cpu_bound_s"] = round(cpu_s / cores, 1)
            result["stage_s"] = {
                k: round(v, 2) for k, v in run.report["reconstruction_stage_s"].items()
            }
    return result


def main() -> None:
    keep_freed_memory()  # as the command line does
    parser = argparse.ArgumentParser()
    add_scan_options(
        parser, "keep the scans here (one folder per object) and reuse them on the next run"
    )
    parser.add_argument(
        "--objects",
        default="bunny",
        help=f"comma-separated from {', '.join(OBJECTS)}; the bunny gets all three variants, "
        "the others the default (corrected) one (default bunny)",
    )
    args = parser.parse_args()
    names = [n.strip() for n in args.objects.split(",") if n.strip()]
    unknown = [n for n in names if n not in OBJECTS]
    if unknown:
        sys.exit(f"bench_reconstruction: unknown object(s) {unknown}; valid: {list(OBJECTS)}")
    require(MESHES, "bench_reconstruction")
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = args.scan_root or Path(tmp) / "scans"
        for name in names:
            scan_dir = mesh_scan(OBJECTS[name], root / name, args.views)
            variants = list(VARIANTS) if name == "bunny" else ["corrected"]
            result = _variants(scan_dir, variants, Path(tmp) / f"results-{name}")
            if name == "bunny":
                out.update(result)  # the bunny's keys stay at the top level, as before
            else:
                out[name] = result
    print(json.dumps(out))


if __name__ == "__main__":
    main()

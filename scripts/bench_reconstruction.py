"""Benchmark: reconstruct a 24-view simulated scan of the Stanford bunny three ways.

Scans (or reuses, with --scan-dir) the bunny from ../shared/data/meshes (largest extent 0.2 m,
default error model: 3 mm / 1 deg hand-eye error) and prints one JSON line with the metrics of
the `pose_only` (nominal X_FC, no ICP), `icp` (ICP + pose graph) and `corrected` (plus hand-eye
correction) variants, and `reconstruct_s` of the corrected run (stereo included).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from reconstruction.metrics import HANDEYE_ERROR_KEYS, SURFACE_METRIC_KEYS
from reconstruction.pipeline import VARIANTS, variant_config
from scanner.captures import CaptureStore
from scanner.config import ProcessingConfig, ScanConfig, with_overrides
from scanner.reconstruct import run_reconstruct
from scanner.scan import run_scan

BUNNY = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes" / "stanford-bunny.obj"
KEYS = (*SURFACE_METRIC_KEYS, *HANDEYE_ERROR_KEYS)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument(
        "--scan-dir",
        type=Path,
        default=None,
        help="reuse this scan (made by a previous run) instead of scanning",
    )
    parser.add_argument("--views", type=int, default=24)
    args = parser.parse_args()
    if not BUNNY.is_file():
        sys.exit(f"bench_reconstruction: {BUNNY} not found (needs ../shared/data)")
    with tempfile.TemporaryDirectory() as tmp:
        scan_dir = args.scan_dir
        if scan_dir is None or not (scan_dir / "scan.yaml").is_file():
            config = replace(
                with_overrides(
                    ScanConfig(), object_spec=str(BUNNY), size_m=0.2, views=args.views, seed=0
                ),
                reconstruct=False,
            )
            scan_dir = run_scan(config, scan_dir or Path(tmp) / "bunny").scan_dir
        out: dict = {"views": len(CaptureStore.open(scan_dir).captured_indices())}
        base = ProcessingConfig()
        for name in VARIANTS:
            rec = variant_config(base.reconstruction, name)
            run = run_reconstruct(
                scan_dir, replace(base, reconstruction=rec), Path(tmp) / f"results-{name}"
            )
            out[name] = {k: round(run.report[k], 4) for k in KEYS if k in run.report}
            if name == "corrected":
                out["reconstruct_s"] = round(run.report["reconstruct_s"], 2)
                out["stage_s"] = {
                    k: round(v, 2) for k, v in run.report["reconstruction_stage_s"].items()
                }
    print(json.dumps(out))


if __name__ == "__main__":
    main()

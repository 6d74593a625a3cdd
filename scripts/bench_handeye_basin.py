"""Benchmark: how far off the nominal hand-eye transform may be for the in-scan correction
to still find it, and whether it says so when it cannot.

One 24-view bunny scan (0.2 m, seed 0, default error model; `--scan DIR` reuses captures),
reconstructed offline (default processing settings) with the nominal X_FC replaced by the true
one moved by a translation (mm) and a rotation (deg) about fixed random axes (seed 7). Each
case: start and final errors, the Chamfer distance on the observed surface, whether the report
says converged. The default start (3 mm / 1 deg) is also run without the coarse stage (the
correction before it existed), for the accuracy and time comparison. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from benchmark_data import MESHES, require
from scipy.spatial.transform import Rotation

from reconstruction.evaluation.metrics import handeye_error
from scanner.configs.scan import ProcessingConfig, ScanConfig, with_overrides
from scanner.reconstruct.scan_views import load_truth_of
from scanner.reconstruct.stages import run_reconstruct
from scanner.scan.run import run_scan
from scanner.scan_dir.manifest import open_scan

BUNNY = MESHES / "stanford-bunny.obj"
# (mm, deg): the diagonal and a few off it.
STARTS = (
    (3, 1),
    (10, 3),
    (20, 6),
    (40, 10),
    (60, 15),
    (3, 10),
    (40, 1),
    (10, 15),
    (60, 3),
    (20, 15),
)


def perturbed(X_FC: np.ndarray, mm: float, deg: float, rng: np.random.Generator) -> np.ndarray:
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    P = np.eye(4)
    P[:3, :3] = Rotation.from_rotvec(math.radians(deg) * axis / np.linalg.norm(axis)).as_matrix()
    P[:3, 3] = 1e-3 * mm * direction / np.linalg.norm(direction)
    return X_FC @ P


def _case(scan, X_FC_true, X_FC_start, processing, out: Path) -> dict:
    report = run_reconstruct(scan, processing, out, X_FC_start).report
    start = handeye_error(X_FC_start, X_FC_true)
    return {
        "start_mm": round(start["handeye_error_mm"], 2),
        "start_deg": round(start["handeye_error_deg"], 3),
        "final_mm": round(report["handeye_error_mm"], 3),
        "final_deg": round(report["handeye_error_deg"], 4),
        "chamfer_observed_mm": round(report["chamfer_observed_mm"], 4),
        "converged_reported": bool(report.get("handeye_converged", False)),
        "reconstruct_s": round(report["reconstruct_s"], 1),
    }


DIAGONAL = 5  # the first STARTS grow together in mm and deg


def _basin(cases: list[dict], good: list[dict], key: str) -> float:
    """The largest diagonal start that ended good, every smaller diagonal start too."""
    basin = 0.0
    for case in cases[:DIAGONAL]:
        if case not in good:
            break
        basin = case[key]
    return basin


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scan", type=Path, help="a captured 24-view bunny scan to reuse")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scan_dir = args.scan
        if scan_dir is None:
            require(BUNNY, "bench_handeye_basin")
            config = with_overrides(ScanConfig(), object_spec=str(BUNNY), seed=0, hangings=1)
            config = replace(config, reconstruct=False)
            scan_dir = run_scan(config, Path(tmp) / "scan").scan_dir
        scan = open_scan(scan_dir)
        X_FC_true = load_truth_of(scan.root)[0].X_FC
        # Today's defaults, not the settings saved with a reused scan.
        rec = ProcessingConfig().reconstruction
        rec = replace(rec, surfaces=replace(rec.surfaces, methods=("poisson",)))
        processing = replace(ProcessingConfig(), reconstruction=rec)
        rng = np.random.default_rng(7)
        cases = []
        for k, (mm, deg) in enumerate(STARTS):
            X_start = perturbed(X_FC_true, mm, deg, rng)
            cases.append(_case(scan, X_FC_true, X_start, processing, Path(tmp) / f"case{k}"))
            print(json.dumps(cases[-1]), file=sys.stderr, flush=True)
            if k == 0:
                without = replace(
                    rec,
                    handeye=replace(rec.handeye, coarse=replace(rec.handeye.coarse, enabled=False)),
                )
                before = _case(
                    scan,
                    X_FC_true,
                    X_start,
                    replace(processing, reconstruction=without),
                    Path(tmp) / "default-without-coarse",
                )
    good = [c for c in cases if c["final_mm"] <= 0.5 and c["final_deg"] <= 0.1]
    bad = [c for c in cases if c["final_mm"] > 1.0 or c["final_deg"] > 0.2]
    failed = [c for c in cases if c not in good]
    print(
        json.dumps(
            {
                "cases": cases,
                "basin_mm": _basin(cases, good, "start_mm"),
                "basin_deg": _basin(cases, good, "start_deg"),
                "not_good": [(c["start_mm"], c["start_deg"]) for c in failed],
                "false_converged": sum(c["converged_reported"] for c in bad),
                "missed": sum(not c["converged_reported"] for c in good),
                "default_case": cases[0],
                "default_case_without_coarse_stage": before,
            }
        )
    )


if __name__ == "__main__":
    main()

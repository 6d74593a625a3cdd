"""Benchmark: the RBF surface beside Poisson on a simulated 24-view bunny scan.

Reconstructs the scan (the default processing, surfaces poisson + rbf) into a temporary results
folder (the scan itself is only read) and prints one JSON line: each surface's Chamfer distance
on the observed part of the true surface, their ratio (rbf / poisson), and `rbf_s`, the time of
the RBF surface stage alone (it runs beside the Poisson solve, as in a scan). `--scan DIR` uses
an existing bunny scan; otherwise the scan is made (or reused) under `--scan-root`, like
bench_reconstruction.py. `--rbf FIELD=VALUE` overrides a `surfaces.rbf_*` setting.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import fields, replace
from pathlib import Path

from benchmark_data import MESHES, add_scan_options, mesh_scan

from reconstruction.surfaces.config import SurfaceConfig
from scanner.configs.scan import ProcessingConfig
from scanner.reconstruct.stages import run_reconstruct

BUNNY = "stanford-bunny.obj"


def _rbf_overrides(items: list[str]) -> dict:
    """FIELD=VALUE pairs for SurfaceConfig's rbf_* fields, typed like the field's default."""
    defaults = {f.name: f.default for f in fields(SurfaceConfig) if f.name.startswith("rbf_")}
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        name = name if name.startswith("rbf_") else f"rbf_{name}"
        if name not in defaults or not value:
            sys.exit(f"bench_rbf: --rbf {item!r}: expected FIELD=VALUE, FIELD one of {defaults}")
        out[name] = type(defaults[name])(value)
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument(
        "--scan", type=Path, default=None, help="an existing bunny scan (read only)"
    )
    add_scan_options(
        parser, "make the scan here (ROOT/bunny) and reuse it on the next run (default: temporary)"
    )
    parser.add_argument(
        "--rbf", action="append", default=[], metavar="FIELD=VALUE", help="e.g. smoothing=2"
    )
    args = parser.parse_args()
    overrides = _rbf_overrides(args.rbf)
    if args.scan is None and not MESHES.is_dir():
        print(f"bench_rbf: skipped, {MESHES} not found (the bunny mesh is needed to scan)")
        return
    base = ProcessingConfig()
    surfaces = replace(base.reconstruction.surfaces, methods=("poisson", "rbf"), **overrides)
    processing = replace(base, reconstruction=replace(base.reconstruction, surfaces=surfaces))
    with tempfile.TemporaryDirectory() as tmp:
        root = args.scan_root or Path(tmp) / "scans"
        scan_dir = args.scan or mesh_scan(BUNNY, root / "bunny", args.views)
        run = run_reconstruct(scan_dir, processing, Path(tmp) / "results")
    report = run.report
    if "surfaces" not in report:
        sys.exit(f"bench_rbf: {scan_dir} has no truth.yaml: nothing to compare against")
    rbf = report["surfaces"]["rbf"]["chamfer_observed_mm"]
    poisson = report["surfaces"]["poisson"]["chamfer_observed_mm"]
    out = {
        "rbf_chamfer_observed_mm": round(rbf, 4),
        "poisson_chamfer_observed_mm": round(poisson, 4),
        "ratio": round(rbf / poisson, 3),
        "rbf_s": round(report["reconstruction_stage_s"]["rbf"], 2),
        "poisson_s": round(report["reconstruction_stage_s"]["poisson"], 2),
        "rbf_completeness_observed_2mm": round(
            report["surfaces"]["rbf"]["completeness_observed_2mm"], 4
        ),
        "poisson_completeness_observed_2mm": round(
            report["surfaces"]["poisson"]["completeness_observed_2mm"], 4
        ),
        "settings": {f: getattr(surfaces, f) for f in sorted(overrides)} or "defaults",
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()

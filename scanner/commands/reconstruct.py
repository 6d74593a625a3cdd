"""`scanner reconstruct` and `scanner merge`: the parsed arguments -> one run or a batch -> a few
printed lines."""

from __future__ import annotations

import argparse
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.reconstruct.command import ReconstructOptions, reconstruct_one, summary_lines


def run_reconstruct_command(args: argparse.Namespace) -> int:
    dirs = args.scan_dirs
    if len(dirs) > 1 and args.out is not None:
        raise ScannerError("--out names one results folder: give it with one SCAN_DIR only")
    options = ReconstructOptions(
        args.config,
        args.calibration,
        args.no_icp,
        args.no_handeye,
        args.formats,
        args.out,
        args.force,
        progress=len(dirs) == 1 and args.ray_address is None,
        units=args.units,
        frame=args.frame,
        decimate=args.decimate,
    )
    if len(dirs) > 1 or args.ray_address is not None or args.workers is not None:
        return _reconstruct_batch(dirs, options, args)
    run = reconstruct_one(dirs[0], options)
    for line in summary_lines(run.report):
        print(line)
    _warn_handeye(run.report)
    print(f"results: {run.results_dir}")
    return 0


def _reconstruct_batch(dirs: list[Path], options, args: argparse.Namespace) -> int:
    import os

    from scanner.reconstruct.batch import run_batch

    def done(outcome) -> None:
        if outcome.ok:
            lines = summary_lines(outcome.report)
            print(f"{outcome.scan_dir}: ok, results {outcome.results_dir}; " + "; ".join(lines))
            _warn_handeye(outcome.report)
        else:
            print(f"{outcome.scan_dir}: FAILED: {outcome.error}", flush=True)

    workers = args.workers or os.cpu_count() or 1
    outcomes = run_batch(dirs, reconstruct_one, options, workers, args.ray_address, done)
    failed = [o for o in outcomes if not o.ok]
    print(f"batch: {len(outcomes) - len(failed)} of {len(outcomes)} scans reconstructed")
    return 1 if failed else 0


def _warn_handeye(report: dict) -> None:
    from scanner.reports.summary import handeye_warning

    warning = handeye_warning(report)
    if warning:
        print(warning)


def run_merge_command(args: argparse.Namespace) -> int:
    from scanner.reconstruct.merge import run_merge

    run = run_merge(args.scan_dirs, args.out, args.config, args.force, progress=True)
    r = run.report
    print(
        f"merge: {len(r['hangings'])} hangings, {r['captures_used']} captures; alignment "
        + ", ".join(
            f"hanging {p['hanging']}: overlap {p['overlap']:.2f}, RMS {p['inlier_rms_mm']:.2f} mm"
            for p in r["hangings"]
            if "overlap" in p
        )
    )
    if "chamfer_mm" in r:
        print(
            f"{r['primary_surface']}: chamfer {r['chamfer_mm']:.3f} mm, completeness(2 mm) "
            f"{r['completeness_2mm']:.3f}; alignment error {r['alignment_error_mm']:.3f} mm"
        )
    _warn_handeye(r)
    print(f"results: {run.results_dir}")
    return 0

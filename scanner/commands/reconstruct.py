"""`scanner reconstruct` and `scanner merge`: their parsers (kept free of heavy imports: the
parser is built for every command) and their runners (the parsed arguments -> one run or a
batch -> a few printed lines)."""

from __future__ import annotations

import argparse
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.commands.arguments import (
    ConfigDefault,
    add_command,
    add_config_file_argument,
    add_config_option,
    add_output_arguments,
    finite_float,
    mesh_formats_arg,
    name_arg,
    path_arg,
    show_formats,
    worker_count,
)

# Where reconstruct's flags take their defaults from when neither they nor --config give a value.
PROCESSING_CONFIG = "scanner.configs.scan:ProcessingConfig"


def add_reconstruct_parser(sub) -> None:
    reconstruct = add_command(
        sub,
        "reconstruct",
        "scanner.commands.reconstruct:run_reconstruct_command",
        help="re-run the reconstruction offline on a saved scan directory",
        description="Rebuild the model from saved captures (never modifies them).",
    )
    reconstruct.add_argument(
        "scan_dirs",
        type=path_arg,
        nargs="+",
        metavar="SCAN_DIR",
        help="scan directories made by `scanner scan`; several are reconstructed in parallel "
        "as Ray tasks, each into its own SCAN_DIR/results[-N]",
    )
    add_config_file_argument(
        reconstruct,
        "processing YAML (stereo:, reconstruction:, ...) (default: the scan's own settings)",
    )
    reconstruct.add_argument(
        "--calibration",
        type=path_arg,
        help="use this calibration's stereo model and X_FC instead of the scan's (default: the "
        "scan's own)",
    )
    add_output_arguments(
        reconstruct,
        "results folder (default SCAN_DIR/results, or results-N when that holds one already)",
        "replace the reconstruction already in --out",
    )
    reconstruct.add_argument(
        "--no-icp",
        action="store_true",
        help="poses from the robot only (default: off, ICP as the settings say)",
    )
    reconstruct.add_argument(
        "--no-handeye",
        action="store_true",
        help="keep X_FC as given, no loop-based correction (default: off, as the settings say)",
    )
    reconstruct.add_argument(
        "--workers",
        type=worker_count,
        help="scans reconstructed at a time (default: the number of CPU cores)",
    )
    reconstruct.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="run the tasks on this Ray cluster (HOST:PORT, or auto) instead of a local Ray; "
        "its nodes need scanner installed and the scans at the same paths (default: local)",
    )
    reconstruct.add_argument(
        "--masks",
        choices=("all", "even", "none"),
        help="imported recordings: the views whose masks restrict the clouds; with even, the "
        "odd views' masks score the model as views it did not use (default: the --config's "
        "masks, all)",
    )
    reconstruct.add_argument(
        "--volume",
        type=finite_float,
        nargs=4,
        metavar=("X", "Y", "Z", "R"),
        help="imported recordings: the sphere the object lies in (centre and radius, metres, in "
        "the recording's world) (default: from the masks, else the cameras' common view)",
    )
    reconstruct.add_argument(
        "--box",
        type=finite_float,
        nargs=6,
        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
        help="imported recordings: instead of --volume, the box the object lies in (its lower "
        "and upper corners, metres, axis-aligned in the recording's world): only what lies in "
        "it is kept (default: none; the volume as --volume says)",
    )
    add_config_option(
        reconstruct,
        "--formats",
        type=mesh_formats_arg,
        help="mesh file formats, comma separated from ply,obj,stl (default %(config_default)s, "
        "or what the scan's or --config's processing.mesh_formats says)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_formats", show_formats),
    )
    add_config_option(
        reconstruct,
        "--units",
        type=name_arg,
        metavar="{m,mm}",
        help="unit of the mesh files' coordinates; not metres: the file names end in _mm "
        "(default: the settings' processing.mesh_export.units, %(config_default)s unless "
        "configured)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_export.units"),
    )
    add_config_option(
        reconstruct,
        "--frame",
        type=name_arg,
        metavar="{world,object}",
        help="frame of the mesh files: the robot's world, or object (centred on the surface, "
        "along its principal axes; file names end in _object); mesh_export.yaml gives X_WO "
        "(default: the settings' processing.mesh_export.frame, %(config_default)s unless "
        "configured)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_export.frame"),
    )
    add_config_option(
        reconstruct,
        "--decimate",
        type=int,
        metavar="N",
        help="at most N triangles per mesh file (quadric decimation; the Hausdorff distance to "
        "the full mesh is reported) (default: the settings' "
        "processing.mesh_export.decimate_triangles, %(config_default)s unless configured)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_export.decimate_triangles", _no_decimation),
    )


def _no_decimation(value) -> str:
    return "no decimation" if value is None else str(value)


def add_merge_parser(sub) -> None:
    merge = add_command(
        sub,
        "merge",
        "scanner.commands.reconstruct:run_merge_command",
        help="align and merge scans of one object (e.g. hung differently) into one model",
        description="Align the passes of two or more scan directories (each of one or more "
        "hangings) into the first one's frame, verify every alignment, and build one model. "
        "An alignment that fails verification writes nothing and exits with code 3.",
    )
    merge.add_argument("scan_dirs", type=path_arg, nargs="+", metavar="SCAN_DIR")
    add_config_file_argument(merge, "processing YAML (default: the first scan's settings)")
    add_output_arguments(
        merge,
        "results folder to create (required, no default)",
        "replace the merged model already in --out",
        required=True,
    )


def reconstruct_saved(scan_dir, options):
    """One saved scan directory reconstructed as what it is: a scan of this product's cell, or
    an imported recording of one camera (pairs of its views make the clouds)."""
    from robots.sensors import sensor_named
    from scanner.reconstruct.command import reconstruct_one
    from scanner.scan_dir.manifest import open_scan

    scan = open_scan(scan_dir)
    if sensor_named(scan.sensor).pairs_of_captures:
        from scanner.recordings.reconstruct import reconstruct_recording_with

        return reconstruct_recording_with(scan, options)
    return reconstruct_one(scan_dir, options)


def run_reconstruct_command(args: argparse.Namespace) -> int:
    from scanner.reconstruct.command import ReconstructOptions, summary_lines

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
        masks=args.masks,
        volume=None if args.volume is None else tuple(args.volume),
        box=None if args.box is None else tuple(args.box),
    )
    if len(dirs) > 1 or args.ray_address is not None or args.workers is not None:
        return _reconstruct_batch(dirs, options, args)
    run = reconstruct_saved(dirs[0], options)
    for line in summary_lines(run.report):
        print(line)
    _warn_handeye(run.report)
    print(f"results: {run.results_dir}")
    _print_page(run)
    return _verdict(run.report)


def _print_page(run) -> None:
    if "model_page" in run.report:
        print(f"3D page: {run.results_dir / run.report['model_page']} (scanner view)")


def _reconstruct_batch(dirs: list[Path], options, args: argparse.Namespace) -> int:
    import os

    from scanner.reconstruct.batch import run_batch
    from scanner.reconstruct.command import summary_lines
    from scanner.reports.self_checks import self_check_failures

    def done(outcome) -> None:
        if outcome.ok:
            lines = summary_lines(outcome.report)
            failures = self_check_failures(outcome.report)
            state = "FAILED its self-checks" if failures else "ok"
            print(
                f"{outcome.scan_dir}: {state}, results {outcome.results_dir}; " + "; ".join(lines)
            )
            _warn_handeye(outcome.report)
        else:
            print(f"{outcome.scan_dir}: FAILED: {outcome.error}", flush=True)

    workers = args.workers or os.cpu_count() or 1
    outcomes = run_batch(dirs, reconstruct_saved, options, workers, args.ray_address, done)
    failed = [o for o in outcomes if not o.ok]
    doubtful = [o for o in outcomes if o.ok and self_check_failures(o.report)]
    print(
        f"batch: {len(outcomes) - len(failed)} of {len(outcomes)} scans reconstructed"
        + (f", {len(doubtful)} of them failed their self-checks" if doubtful else "")
    )
    # A result that failed its self-checks counts as a failed scan: 1 as for any failure.
    return 1 if failed or doubtful else 0


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
    _print_page(run)
    return _verdict(r)


def _verdict(report: dict) -> int:
    """Print the verdict of a result's self-checks as the last line; the exit code."""
    from scanner.reports.self_checks import exit_code, verdict_line

    print(verdict_line(report))
    return exit_code(report)

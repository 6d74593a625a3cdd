"""The `scanner` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.calibrate.arguments import add_calibrate_parser
from scanner.calibrate.exchange import add_export_parser, add_import_parser
from scanner.cli.arguments import (
    ConfigDefault,
    ScannerArgumentParser,
    add_config_option,
    add_driver_argument,
    add_output_arguments,
    add_seed_argument,
    for_flag,
    mesh_formats_arg,
    name_arg,
    path_arg,
    positive_float,
    seconds_list,
    show_formats,
    worker_count,
)
from scanner.inspect.command import add_inspect_parser
from scanner.monitor.command import add_monitor_parser

BUILTIN_HELP = "vase, bracket, pebble"
# Where scan's flags take their defaults from when neither they nor --config give a value.
SCAN_CONFIG = "scanner.scan.config:ScanConfig"


def build_parser() -> argparse.ArgumentParser:
    parser = ScannerArgumentParser(
        prog="scanner",
        description="Eye-in-hand 3D modelling with a Staubli RX60 and a wrist stereo camera. "
        "Runs in a Drake simulation unless a hardware driver is configured.",
    )
    parser.add_argument("--version", action="version", version=f"scanner {_version()}")
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=ScannerArgumentParser
    )
    _add_scan_parser(sub)
    add_calibrate_parser(sub)
    _add_reconstruct_parser(sub)
    _add_merge_parser(sub)
    _add_preview_parser(sub)
    add_export_parser(sub)
    add_import_parser(sub)
    add_inspect_parser(sub)
    add_monitor_parser(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("scanner")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


def _add_scan_parser(sub) -> None:
    scan = sub.add_parser(
        "scan",
        help="scan an object: plan viewpoints, move, capture stereo pairs, reconstruct",
        description="Scan an object in the simulated work cell: viewpoints on a sphere around it, "
        "collision-free motions, stereo captures saved to a scan directory, then reconstruction.",
    )
    add_config_option(
        scan,
        "--object",
        type=name_arg,
        help=f"built-in object ({BUILTIN_HELP}), a mesh file (.obj/.ply/.stl), or the name of "
        "a mesh in a folder of $SCANNER_MESH_PATH (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "object"),
    )
    add_config_option(
        scan,
        "--size",
        type=positive_float,
        help="largest extent of the object in metres (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "cell.object_size_m"),
    )
    add_config_option(
        scan,
        "--views",
        type=int,
        help="number of views (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "views.count"),
    )
    add_config_option(
        scan,
        "--radius",
        type=positive_float,
        help="distance of the rig from the scan centre in metres (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "views.radius_m"),
    )
    add_output_arguments(
        scan,
        "scan directory to create (default scans/OBJECT-TIMESTAMP)",
        "replace an existing scan directory given with --out",
    )
    add_seed_argument(scan)
    add_config_option(
        scan,
        "--max-extra-views",
        type=int,
        metavar="K",
        help="after each hanging's planned views, up to K next-best views where the model so "
        "far leaves the most surface unseen (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "views.max_extra_views"),
    )
    add_config_option(
        scan,
        "--hangings",
        type=int,
        help="passes over the object, re-hung between them (the simulator turns it; on "
        "hardware the operator is asked), aligned and merged into one model "
        "(default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "hangings"),
    )
    scan.add_argument(
        "--monitor",
        action="store_true",
        help="watch the cell with the static stereo camera while scanning: an intrusion stops "
        "the arm and holds captures until the cell is clear (default: off, or monitor.enabled)",
    )
    scan.add_argument(
        "--intruder",
        type=seconds_list,
        metavar="SECONDS[,SECONDS...]",
        help="simulation with --monitor: a forearm reaches into the cell at these times (s on "
        "the monitor's clock) (default: none)",
    )
    scan.add_argument(
        "--config",
        type=path_arg,
        help="scan configuration YAML; flags given win over it (default: none, the built-in "
        "defaults stated here)",
    )
    scan.add_argument(
        "--calibration",
        type=path_arg,
        help="calibration file from `scanner calibrate` (stereo model and hand-eye X_FC) "
        "(default: the --config file's calibration_file, else the nominal camera and mount)",
    )
    add_driver_argument(scan, "scan")
    scan.add_argument(
        "--resume",
        type=path_arg,
        metavar="DIR",
        help="continue an interrupted scan (default: none, start a new scan)",
    )
    scan.add_argument(
        "--meshcat",
        action="store_true",
        help="show the robot, planned paths and the growing cloud live in Drake's Meshcat "
        "(default: off)",
    )
    scan.add_argument(
        "--print-config",
        action="store_true",
        help="print the effective configuration (defaults, --config, flags) as YAML and exit "
        "(default: off)",
    )
    scan.add_argument(
        "--plan-only",
        action="store_true",
        help="plan the views, tour and motions without moving the robot or capturing: writes "
        "plan.json and plan.png to --out (default scans/OBJECT-TIMESTAMP-plan) and lists the "
        "unreachable views (default: off)",
    )


def _add_reconstruct_parser(sub) -> None:
    reconstruct = sub.add_parser(
        "reconstruct",
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
    reconstruct.add_argument(
        "--config",
        type=path_arg,
        help="processing YAML (stereo:, reconstruction:, ...) (default: the scan's own settings)",
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
    add_config_option(
        reconstruct,
        "--formats",
        type=mesh_formats_arg,
        help="mesh file formats, comma separated from ply,obj,stl (default %(config_default)s, "
        "or what the scan's or --config's processing.mesh_formats says)",
        config=ConfigDefault("scanner.scan.config:ProcessingConfig", "mesh_formats", show_formats),
    )
    export = "scanner.scan.config:ProcessingConfig"
    add_config_option(
        reconstruct,
        "--units",
        type=name_arg,
        metavar="{m,mm}",
        help="unit of the mesh files' coordinates; not metres: the file names end in _mm "
        "(default: the settings' processing.mesh_export.units, %(config_default)s unless "
        "configured)",
        config=ConfigDefault(export, "mesh_export.units"),
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
        config=ConfigDefault(export, "mesh_export.frame"),
    )
    add_config_option(
        reconstruct,
        "--decimate",
        type=int,
        metavar="N",
        help="at most N triangles per mesh file (quadric decimation; the Hausdorff distance to "
        "the full mesh is reported) (default: the settings' "
        "processing.mesh_export.decimate_triangles, %(config_default)s unless configured)",
        config=ConfigDefault(export, "mesh_export.decimate_triangles", _no_decimation),
    )


def _no_decimation(value) -> str:
    return "no decimation" if value is None else str(value)


def _add_merge_parser(sub) -> None:
    merge = sub.add_parser(
        "merge",
        help="align and merge scans of one object (e.g. hung differently) into one model",
        description="Align the passes of two or more scan directories (each of one or more "
        "hangings) into the first one's frame, verify every alignment, and build one model. "
        "An alignment that fails verification writes nothing and exits with code 3.",
    )
    merge.add_argument("scan_dirs", type=path_arg, nargs="+", metavar="SCAN_DIR")
    merge.add_argument(
        "--config",
        type=path_arg,
        help="processing YAML (default: the first scan's settings)",
    )
    add_output_arguments(
        merge,
        "results folder to create (required, no default)",
        "replace the merged model already in --out",
        required=True,
    )


def _add_preview_parser(sub) -> None:
    preview = sub.add_parser(
        "preview",
        help="render the simulated work cell and one stereo pair to PNG files",
        description="Build the simulated cell with an object, move the arm to one reachable "
        "viewpoint and render an overview and the stereo pair (with lens distortion and noise).",
    )
    preview.add_argument(
        "--object",
        default="vase",
        help=f"built-in object ({BUILTIN_HELP}) or a mesh file (default %(default)s)",
    )
    preview.add_argument(
        "--out",
        type=path_arg,
        default=Path("out/preview"),
        help="output folder (default %(default)s)",
    )
    add_seed_argument(preview, default=0)


def _scan(args: argparse.Namespace) -> int:
    import datetime

    from scanner.reconstruct.progress import ProgressBar
    from scanner.scan.config import load_scan_config, with_overrides
    from scanner.scan.run import run_scan

    flags = dict(
        object_spec=args.object,
        size_m=args.size,
        views=args.views,
        radius_m=args.radius,
        seed=args.seed,
        calibration_file=str(args.calibration) if args.calibration else None,
        driver=args.driver,
        hangings=args.hangings,
        max_extra_views=args.max_extra_views,
        monitor=args.monitor or None,
        intruder_start_s=args.intruder,
    )
    if args.plan_only and (args.resume is not None or args.meshcat):
        raise ScannerError("--plan-only plans a new scan: do not give --resume or --meshcat")
    if args.resume is not None:
        if args.out is not None or args.force:
            raise ScannerError("--resume DIR continues DIR; do not give --out or --force")
        from scanner.scan.config import resume_request
        from scanner.scan.manifest import open_scan

        given = {k: v for k, v in flags.items() if v is not None}
        saved = open_scan(args.resume).config
        config = resume_request(saved, args.config, **given)
        out = None
    else:
        config = with_overrides(load_scan_config(args.config), **flags)
        if args.print_config:
            import yaml

            from scanner.scan.config import scan_config_to_dict

            print(yaml.safe_dump(scan_config_to_dict(config), sort_keys=False), end="")
            return 0
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        name = Path(config.object).stem
        if args.plan_only:
            from scanner.plan_only.plan import plan_command

            plan_dir = args.out or Path("scans") / f"{name}-{stamp}-plan"
            return plan_command(config, plan_dir, args.force)
        out = args.out or Path("scans") / f"{name}-{stamp}"
    with ProgressBar("views") as bar:
        result = run_scan(
            config, out, args.resume, args.force, bar.update, args.meshcat, show_stages=True
        )
    for line in scan_result_lines(result):
        print(line)
    r = result.report
    if r["status"] == "interrupted":
        print(f"continue with: scanner scan --resume {result.scan_dir}")
        return 130
    return 0


def scan_result_lines(result) -> list[str]:
    """What `scanner scan` prints at the end: the run, the headline figures with their verdicts
    (with truth), a hand-eye warning if any, and where the results and their summary are."""
    from scanner.reconstruct.command import metrics_line
    from scanner.reports.summary import handeye_warning

    r = result.report
    results = result.scan_dir / "results"
    lines = [
        f"scan: {r['views_captured']}/{r['views_planned']} views captured, "
        f"{r['views_skipped']} skipped; robot motion {r['robot_motion_s']:.1f} s, "
        f"wall {r['wall_s']:.1f} s; status {r['status']}",
        metrics_line(r),
        handeye_warning(r),
        f"scan directory: {result.scan_dir}",
        f"report: {results / 'report.json'}",
    ]
    if (results / "summary.md").is_file():
        lines.append(f"summary: {results / 'summary.md'}")
    return [line for line in lines if line]


def _reconstruct(args: argparse.Namespace) -> int:
    from scanner.reconstruct.command import ReconstructOptions, reconstruct_one, summary_lines

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
    from scanner.reconstruct.command import reconstruct_one, summary_lines

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


def _merge(args: argparse.Namespace) -> int:
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


def _run(args: argparse.Namespace) -> int:
    if getattr(args, "out", None) is not None:
        from scanner.reconstruct.results_folder import require_creatable

        require_creatable(args.out, "--out")
    if args.command == "scan":
        return _scan(args)
    if args.command == "calibrate":
        from scanner.calibrate.cli import run_calibrate_command

        return run_calibrate_command(args)
    if args.command == "preview":
        from robots.simulation.truth import ErrorModel
        from scanner.scan.preview import run_preview

        for_flag("--seed", lambda: ErrorModel(seed=args.seed))
        result = run_preview(args.object, args.out, args.seed)
        print(f"overview: {result.overview_png}")
        print(f"stereo pair: {result.left_png} {result.right_png}")
        return 0
    if args.command == "reconstruct":
        return _reconstruct(args)
    if args.command == "merge":
        return _merge(args)
    if args.command == "export":
        from scanner.calibrate.exchange import run_export

        return run_export(args)
    if args.command == "monitor":
        from scanner.monitor.command import run_monitor_command

        return run_monitor_command(args)
    if args.command == "inspect":
        from scanner.inspect.command import run_inspect_command

        return run_inspect_command(args)
    if args.command == "import-calibration":
        from scanner.calibrate.exchange import run_import

        return run_import(args)
    raise AssertionError(f"unhandled command {args.command}")


def _quiet_libraries() -> None:
    """Library chatter stays off the console: OpenCV and Open3D failures surface as our
    messages (their results are checked), Drake's context allocation is logged at INFO."""
    import logging

    import cv2
    import open3d as o3d
    import pydrake.common  # noqa: F401  (sets up the "drake" logger, which we then quieten)

    logging.getLogger("drake").setLevel(logging.WARNING)
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    _quiet_libraries()
    try:
        return _run(args)
    except ScannerError as e:
        message = " ".join(str(e).split())  # one line, whatever a library put into it
        print(f"scanner: error: {message}", file=sys.stderr)
        return e.exit_code
    except OSError as e:
        # Reading or writing failed where no stage turned it into a message of its own.
        where = f"{e.filename}: " if e.filename else ""
        print(f"scanner: error: {where}{e.strerror or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("scanner: interrupted", file=sys.stderr)
        return 130


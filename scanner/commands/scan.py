"""`scanner scan` and `scanner preview`: their parsers (kept free of heavy imports: the parser is
built for every command, `--help` included) and their runners (the parsed arguments ->
configuration -> run -> a few printed lines)."""

from __future__ import annotations

import argparse
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.commands.arguments import (
    LENGTH_HELP,
    ConfigDefault,
    LengthOption,
    add_command,
    add_config_file_argument,
    add_config_option,
    add_driver_argument,
    add_output_arguments,
    add_seed_argument,
    hangings_arg,
    name_arg,
    path_arg,
    seconds_list,
    typed_text,
)
from scanner.configs.flags import for_flag

BUILTIN_HELP = "vase, bracket, pebble"
# Where scan's flags take their defaults from when neither they nor --config give a value.
SCAN_CONFIG = "scanner.configs.scan:ScanConfig"


def add_scan_parser(sub) -> None:
    scan = add_command(
        sub,
        "scan",
        "scanner.commands.scan:run_scan_command",
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
        action=LengthOption,
        help=f"largest extent of the object; {LENGTH_HELP} (default %(config_default)s m)",
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
        action=LengthOption,
        help=f"distance of the rig from the scan centre; {LENGTH_HELP} (default "
        "%(config_default)s m)",
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
        type=hangings_arg,
        metavar="N|auto",
        help="passes over the object, re-hung between them (the simulator turns it; on "
        "hardware the operator is asked), aligned and merged into one model; auto: another "
        "hanging, turned as the scanner computes, until coverage_target of the surface is "
        "seen (at most max_hangings) (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "hangings"),
    )
    add_config_option(
        scan,
        "--presentation",
        choices=("hanging", "table", "turntable"),
        help="how the object is offered and turned between passes: hanging (from the rod, "
        "re-hung by a person), turntable (turned by the scanner; --hangings is then its "
        "number of passes) or table (lying on the support table, laid on another face by a "
        "person) (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "presentation"),
    )
    add_config_option(
        scan,
        "--operator",
        choices=("instructed", "random"),
        help="simulation: who re-hangs the object; instructed follows the scanner's "
        "instruction with a person's 10-25 deg error, random turns it 90-180 deg whatever "
        "was asked (the worst case) (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "error_model.operator"),
    )
    add_config_option(
        scan,
        "--robot",
        type=name_arg,
        metavar="ARM",
        help="the arm: rx60 (the Staubli RX60) or the path of an arm file, e.g. "
        "scanner/configs/arms/ur5e.yaml (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "robot"),
    )
    add_config_option(
        scan,
        "--sensor",
        type=name_arg,
        help="what measures depth: stereo (the stereo pair, SGBM) or rgbd (a depth camera with "
        "a colour camera, configured under rgbd:) (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "sensor"),
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
    add_config_file_argument(
        scan,
        "scan configuration YAML; flags given win over it (default: none, the built-in "
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


def add_preview_parser(sub) -> None:
    preview = add_command(
        sub,
        "preview",
        "scanner.commands.scan:run_preview_command",
        help="render the simulated work cell and one stereo pair to PNG files",
        description="Build the simulated cell with an object, move the arm to one reachable "
        "viewpoint and render an overview and the stereo pair (with lens distortion and noise).",
    )
    preview.add_argument(
        "--object",
        default="vase",
        help=f"built-in object ({BUILTIN_HELP}) or a mesh file (default %(default)s)",
    )
    add_output_arguments(
        preview,
        "output folder (default out/preview, or out/preview-N when that holds one already)",
        "replace the preview already in --out",
    )
    add_seed_argument(preview, default=0)


def run_scan_command(args: argparse.Namespace) -> int:
    import datetime

    from scanner.configs.scan import load_scan_config, with_overrides
    from scanner.reconstruct.progress import ProgressBar
    from scanner.reports.self_checks import exit_code, verdict_line
    from scanner.scan.run import run_scan

    require_plausible_lengths(args)
    flags = dict(
        object_spec=args.object,
        size_m=args.size,
        views=args.views,
        radius_m=args.radius,
        seed=args.seed,
        calibration_file=str(args.calibration) if args.calibration else None,
        driver=args.driver,
        hangings=args.hangings,
        presentation=args.presentation,
        max_extra_views=args.max_extra_views,
        monitor=args.monitor or None,
        intruder_start_s=args.intruder,
        operator=args.operator,
        sensor=args.sensor,
        robot=args.robot,
    )
    if args.plan_only and (args.resume is not None or args.meshcat):
        raise ScannerError("--plan-only plans a new scan: do not give --resume or --meshcat")
    if args.resume is not None:
        if args.out is not None or args.force:
            raise ScannerError("--resume DIR continues DIR; do not give --out or --force")
        from scanner.configs.scan import resume_request
        from scanner.scan_dir.manifest import open_scan

        given = {k: v for k, v in flags.items() if v is not None}
        saved = open_scan(args.resume).config
        config = resume_request(saved, args.config, **given)
        out = None
    else:
        config = with_overrides(load_scan_config(args.config), **flags)
        if args.print_config:
            import yaml

            from scanner.configs.scan import scan_config_to_dict

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
            config,
            out,
            args.resume,
            args.force,
            bar.update,
            args.meshcat,
            show_stages=True,
            on_model=lambda path: print(f"model: {path}", flush=True),
        )
    for line in scan_result_lines(result):
        print(line)
    r = result.report
    if r["status"] == "interrupted":
        print(f"continue with: scanner scan --resume {result.scan_dir}")
        return 130
    if "self_checks" not in r:
        return 0  # captured only (reconstruct: false): nothing was checked
    print(verdict_line(r))
    return exit_code(r)


def require_plausible_lengths(args: argparse.Namespace) -> None:
    """--size and --radius beyond what the cell holds or the arm reaches are a unit typed
    wrongly (200 for 200 mm): refused with both readings."""
    from reconstruction.common.lengths import require_below
    from robots.models.workcell import MAX_OBJECT_SIZE_M
    from scanner.configs.views import MAX_RADIUS_M

    limits = (
        ("size", MAX_OBJECT_SIZE_M, "more than the largest object the cell holds"),
        ("radius", MAX_RADIUS_M, "more than any view of the arm's could be"),
    )
    for name, limit_m, what in limits:
        value = getattr(args, name)
        if value is not None and value > limit_m:
            require_below(f"--{name}", typed_text(args, name), value, limit_m, what)


def _reach_words(report: dict) -> str:
    share = report.get("reachable_fraction")
    return "" if share is None else f"; the arm reaches {100 * share:.0f} % of the view sphere"


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
        f"wall {r['wall_s']:.1f} s; status {r['status']}{_reach_words(r)}",
        metrics_line(r),
        handeye_warning(r),
        f"scan directory: {result.scan_dir}",
        f"report: {results / 'report.json'}",
    ]
    if (results / "summary.md").is_file():
        lines.append(f"summary: {results / 'summary.md'}")
    if "model_page" in r:
        lines.append(f"3D page: {results / r['model_page']} (scanner view {result.scan_dir})")
    return [line for line in lines if line]


def run_preview_command(args: argparse.Namespace) -> int:
    from robots.simulation.truth import ErrorModel
    from scanner.scan.preview import run_preview

    for_flag("--seed", lambda: ErrorModel(seed=args.seed))
    out = args.out
    if out is None:
        from scanner.scan_dir.results_folder import free_results_dir

        out = free_results_dir(Path("out"), "overview.png", "preview")
    result = run_preview(args.object, out, args.seed)
    print(f"overview: {result.overview_png}")
    print(f"stereo pair: {result.left_png} {result.right_png}")
    return 0

"""`scanner scan` and `scanner preview`: the parsed arguments -> configuration -> run -> a few
printed lines."""

from __future__ import annotations

import argparse
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.configs.flags import for_flag


def run_scan_command(args: argparse.Namespace) -> int:
    import datetime

    from scanner.configs.scan import load_scan_config, with_overrides
    from scanner.reconstruct.progress import ProgressBar
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


def run_preview_command(args: argparse.Namespace) -> int:
    from robots.simulation.truth import ErrorModel
    from scanner.scan.preview import run_preview

    for_flag("--seed", lambda: ErrorModel(seed=args.seed))
    result = run_preview(args.object, args.out, args.seed)
    print(f"overview: {result.overview_png}")
    print(f"stereo pair: {result.left_png} {result.right_png}")
    return 0

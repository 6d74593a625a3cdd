"""`scanner calibrate` arguments -> configuration -> run -> a few printed lines."""

from __future__ import annotations

import argparse
import datetime
import re
from dataclasses import replace
from pathlib import Path

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.pose_files import pose_format
from reconstruction.common.errors import ScannerError
from scanner.calibrate.config import CalibrateConfig, load_calibrate_config
from scanner.calibrate.eye_in_hand import run_eye_in_hand
from scanner.calibrate.eye_to_hand import run_eye_to_hand, solve_eye_to_hand_directory
from scanner.calibrate.offline import (
    OfflineOptions,
    calibrate_cameras_directory,
    calibrate_directory,
    cameras_only_images,
)
from scanner.calibrate.report import error_text, quality_lines
from scanner.configs.flags import for_flag
from scanner.configs.references import absolute_arm_file, check_robot
from scanner.reconstruct.progress import ProgressBar
from scanner.scan_dir.results_folder import require_replaceable


def _board_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise ScannerError(f"--board-size: expected COLSxROWS such as 7x11, got '{text}'")
    return int(m.group(1)), int(m.group(2))


def board_from_args(args: argparse.Namespace, base: BoardSpec | None) -> BoardSpec | None:
    """The board from the flags on top of `base` (None: no flag and no base -> None)."""
    changes = {}
    if args.board is not None:
        changes["kind"] = args.board
    if args.board_size is not None:
        changes["cols"], changes["rows"] = _board_size(args.board_size)
    if args.board_spacing is not None:
        changes["spacing_m"] = args.board_spacing
    if args.marker_size is not None:
        changes["marker_m"] = args.marker_size
    if args.dictionary is not None:
        changes["dictionary"] = args.dictionary
    if args.inverted:
        changes["inverted"] = True
    if not changes:
        return base
    kind = changes.get("kind", base.kind if base else None)
    if kind != "charuco" and ("marker_m" in changes or "dictionary" in changes):
        raise ScannerError("--marker-size and --dictionary apply only to --board charuco")
    if base is None:
        if "kind" not in changes or "cols" not in changes or "spacing_m" not in changes:
            raise ScannerError(
                "describe the board with --board KIND --board-size COLSxROWS --board-spacing M"
            )
        if changes["kind"] == "charuco" and "marker_m" not in changes:
            changes["marker_m"] = 0.75 * changes["spacing_m"]
        return for_flag(_board_flags(changes), lambda: BoardSpec(**changes))
    return for_flag(_board_flags(changes), lambda: replace(base, **changes))


BOARD_FLAGS = {
    "kind": "--board",
    "cols": "--board-size",
    "spacing_m": "--board-spacing",
    "marker_m": "--marker-size",
    "dictionary": "--dictionary",
    "inverted": "--inverted",
}


def _board_flags(changes: dict) -> str:
    """The flags that described the board, for its errors (which may involve several)."""
    return ", ".join(flag for key, flag in BOARD_FLAGS.items() if key in changes)


POSE_FLAGS = {
    "layout": "--pose-layout",
    "euler": "--euler",
    "length_unit": "--length-unit",
    "angle_unit": "--angle-unit",
}


def pose_format_from_args(args: argparse.Namespace):
    """The preset, then each flag on it; a bad value is reported with its flag (each field is
    checked on its own, so the order does not matter)."""
    fmt = for_flag("--pose-convention", lambda: pose_format(args.pose_convention))
    for key, flag in POSE_FLAGS.items():
        value = getattr(args, flag[2:].replace("-", "_"))
        if value is not None:
            fmt = for_flag(flag, lambda f=fmt, k=key, v=value: replace(f, **{k: v}))
    return replace(fmt, inverse=True) if args.inverse_poses else fmt


def _stamp() -> str:
    return datetime.datetime.now().strftime("%Y%m%d-%H%M%S")


def _config(args: argparse.Namespace) -> CalibrateConfig:
    config = load_calibrate_config(args.config)
    if args.seed is not None:
        model = for_flag("--seed", lambda: replace(config.error_model, seed=args.seed))
        config = replace(config, error_model=model)
    if args.stations is not None:
        stations = for_flag("--stations", lambda: replace(config.stations, count=args.stations))
        config = replace(config, stations=stations)
    if args.sensor is not None:
        config = for_flag("--sensor", lambda: replace(config, sensor=args.sensor))
    if args.robot is not None:
        check_robot(args.robot, "--robot")
        config = replace(config, robot=absolute_arm_file(args.robot))
    if args.driver is not None:
        if args.offline is not None:
            raise ScannerError("--offline calibrates recorded data; do not give --driver")
        config = replace(config, driver=args.driver)
    board = board_from_args(args, config.board)
    if board is not config.board:
        config = replace(config, board=board)
    if args.robot_offsets:
        if args.eye_to_hand:
            raise ScannerError(
                "--robot-offsets applies to eye-in-hand calibrations, not --eye-to-hand"
            )
        solver = replace(config.solver, robot_offsets=True)
        config = for_flag("--robot-offsets", lambda: replace(config, solver=solver))
    e2h = config.eye_to_hand
    if args.held_out is not None:
        e2h = for_flag("--held-out", lambda: replace(e2h, held_out=args.held_out))
    if args.grid_spacing is not None:
        e2h = for_flag("--grid-spacing", lambda: replace(e2h, grid_spacing_m=args.grid_spacing))
    return replace(config, eye_to_hand=e2h)


def _print_cameras_summary(run) -> None:
    r = run.report
    print(
        f"camera calibration (no robot poses): board found in {r['boards_found']} of "
        f"{r['images']} images"
    )
    if "stereo_rms_px" in r:
        print(
            f"stereo RMS reprojection: {r['stereo_rms_px']:.3f} px; rectified epipolar error: "
            f"median {r['epipolar_median_px']:.3f} px, p95 {r['epipolar_p95_px']:.3f} px; "
            f"baseline {1e3 * r['baseline_m']:.2f} mm"
        )
    else:
        print(f"RMS reprojection: {r['camera_rms_px']:.3f} px")
    print("hand-eye: not calibrated (the camera tool's nominal X_FC is in the file)")
    print(f"calibration file: {run.calibration_file}")
    print(f"report: {run.results_dir / 'report.txt'}")


def _print_summary(report: dict, results_dir: Path, calibration_file: Path) -> None:
    line = f"calibration: {report['poses_used']}/{report['poses']} poses used"
    if report["poses_outliers"]:
        line += f", outliers rejected: {', '.join(report['poses_outliers'])}"
    if report["poses_board_not_found"]:
        line += f", board not found in: {', '.join(report['poses_board_not_found'])}"
    print(line)
    if report.get("stereo_rms_px") is not None:
        print(f"stereo RMS reprojection: {report['stereo_rms_px']:.3f} px")
    scatter = max(report["board_scatter_mm"])
    print(
        f"hand-eye RMS reprojection: {report['reprojection_rms_px']:.3f} px; "
        f"board-in-base scatter {scatter:.2f} mm (largest axis std)"
    )
    for line in quality_lines(report):
        print(line)
    truth = report.get("truth")
    if truth:
        print(f"error against the simulator's truth: {error_text(truth)}")
    print(f"calibration file: {calibration_file}")
    print(f"report: {results_dir / 'report.txt'}")


def _print_eye_to_hand(report: dict, results: Path) -> None:
    h = report["held_out"]
    print(
        f"eye-to-hand: {report['fit_points_used']} grid points used, "
        f"{report['fit_points_rejected']} rejected; held-out error over {h['count']} points: "
        f"mean {h['mean_distance_mm']:.3f} mm, std {h['std_distance_mm']:.3f} mm"
    )
    print(f"report: {results / 'eye_to_hand_report.txt'}")


OFFLINE_ONLY = (
    "pose_convention",
    "pose_layout",
    "euler",
    "length_unit",
    "angle_unit",
    "inverse_poses",
    "pose_file",
    "intrinsics",
)
EYE_TO_HAND_ONLY = ("held_out", "grid_spacing")


def _require_mode(args: argparse.Namespace) -> None:
    """Options of one mode are refused in the others (rather than silently ignored)."""

    def given(names):
        return [n for n in names if getattr(args, n) not in (None, False)]

    def flag(name):
        return "--" + name.replace("_", "-")

    if args.offline is None and given(OFFLINE_ONLY):
        raise ScannerError(f"{flag(given(OFFLINE_ONLY)[0])} applies only with --offline DIR")
    if not args.eye_to_hand and given(EYE_TO_HAND_ONLY):
        raise ScannerError(f"{flag(given(EYE_TO_HAND_ONLY)[0])} applies only with --eye-to-hand")


def run_calibrate_command(args: argparse.Namespace) -> int:
    _require_mode(args)
    config = _config(args)
    if args.resume is not None and (args.eye_to_hand or args.offline is not None):
        raise ScannerError("--resume continues an eye-in-hand run, not --eye-to-hand/--offline")
    if args.eye_to_hand and args.offline is not None:
        pose_flags = [n for n in OFFLINE_ONLY if getattr(args, n) not in (None, False)]
        if pose_flags:
            raise ScannerError(
                f"--{pose_flags[0].replace('_', '-')}: --eye-to-hand --offline reads the poses "
                "its run recorded (metres); give no pose options"
            )
        report, results = solve_eye_to_hand_directory(args.offline, config, args.out, args.force)
        _print_eye_to_hand(report, results)
        return 0
    if args.eye_to_hand:
        out = args.out or Path("calibrations") / f"eye-to-hand-{_stamp()}"
        require_replaceable(out / "results", "eye_to_hand.yaml", args.force, "calibration")
        with ProgressBar("points") as bar:
            report = run_eye_to_hand(config, out, progress=bar.update)
        _print_eye_to_hand(report, out / "results")
        print(f"recorded frames and poses: {out} (solve again: --eye-to-hand --offline {out})")
        return 0
    if args.offline is not None:
        root = args.offline
        is_store = (root / "scan.yaml").is_file()
        board = board_from_args(args, None)
        fmt = pose_format_from_args(args)
        # The arm named (--robot, the configuration) wins over the one a directory records.
        robot = None if config.robot == "rx60" else config.robot
        options = OfflineOptions(board, fmt, args.pose_file, ".txt", args.intrinsics, robot)
        out = args.out
        if out is None and not is_store:
            out = Path("calibrations") / f"{root.name}-{_stamp()}"
        if cameras_only_images(root, options) is not None:
            cameras = calibrate_cameras_directory(root, options, config.solver, out, args.force)
            _print_cameras_summary(cameras)
            return 0
        run = calibrate_directory(root, options, config.solver, out, force=args.force)
        _print_summary(run.report, run.results_dir, run.calibration_file)
        return 0
    if args.resume is not None:
        if args.out is not None or args.force:
            raise ScannerError("--resume DIR continues DIR; do not give --out or --force")
        out = args.resume
    else:
        out = args.out or Path("calibrations") / f"calib-{_stamp()}"
    with ProgressBar("stations") as bar:
        run = run_eye_in_hand(
            config, out, args.force, progress=bar.update, resume=args.resume is not None
        )
    _print_summary(run.report, run.results_dir, run.calibration_file)
    return 0

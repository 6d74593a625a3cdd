"""`scanner export` and `scanner import-calibration`: the calibration file to and from the files
OpenCV and ROS users already have (the formats: reconstruction/calibration/exchange.py).

The parsers are built for every command, so the heavy imports wait for the runners.
"""

from __future__ import annotations

import argparse
import datetime
import os
import re
import shutil
import tempfile
from contextlib import suppress
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.commands.arguments import (
    add_command,
    add_output_arguments,
    name_arg,
    path_arg,
)
from scanner.configs.flags import for_flag

EXPORT_FORMATS = ("opencv", "ros", "ros-tf")
IMPORT_FORMATS = ("opencv", "ros")
TF_ONLY = ("parent_frame", "child_frame")
OPENCV_ONLY = ("image_size", "length_unit")


def image_size_arg(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) <= 0 or int(m.group(2)) <= 0:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT in pixels such as 1280x960, got '{text}'"
        )
    return int(m.group(1)), int(m.group(2))


def add_export_parser(sub) -> None:
    export = add_command(
        sub,
        "export",
        "scanner.commands.exchange:run_export",
        help="write a calibration file as OpenCV or ROS files (camera pair, hand-eye transform)",
        description="Write the stereo camera of a calibration file as OpenCV stereo_calib "
        "files (intrinsics.yml, extrinsics.yml; T in metres) or ROS camera_info files "
        "(left.yaml, right.yaml), or its hand-eye X_FC as a ROS static transform "
        "(hand_eye_tf.yaml with the static_transform_publisher commands).",
    )
    # Names are checked by the command (one line listing the valid ones), as `calibrate` does.
    export.add_argument(
        "calibration", type=path_arg, metavar="CALIBRATION_FILE", help="from `scanner calibrate`"
    )
    export.add_argument(
        "--format",
        type=name_arg,
        required=True,
        help="opencv, ros or ros-tf (required, no default)",
    )
    add_output_arguments(
        export,
        "folder to write into (required, no default)",
        "replace files of this format already in --out",
        required=True,
    )
    export.add_argument(
        "--parent-frame", type=name_arg, help="ros-tf: the flange frame (default tool0)"
    )
    export.add_argument(
        "--child-frame",
        type=name_arg,
        help="ros-tf: the left camera's optical frame, z forward (default camera_optical_frame)",
    )


def add_import_parser(sub) -> None:
    imp = add_command(
        sub,
        "import-calibration",
        "scanner.commands.exchange:run_import",
        help="make a calibration file from OpenCV or ROS stereo calibration files",
        description="Read OpenCV stereo_calib files (DIR/intrinsics.yml, DIR/extrinsics.yml) "
        "or ROS camera_info files (DIR/left.yaml, DIR/right.yaml) and write a calibration file "
        "that scan and reconstruct read with --calibration. X_FC comes from --hand-eye, else it "
        "is the camera tool's nominal mount (what a scan assumes without a calibration).",
    )
    imp.add_argument("folder", type=path_arg, metavar="DIR", help="folder holding the files")
    imp.add_argument(
        "--format", type=name_arg, required=True, help="opencv or ros (required, no default)"
    )
    add_output_arguments(
        imp,
        "calibration file to write (required, no default)",
        "replace an existing --out file",
        required=True,
        dest="out_file",
        metavar="FILE",
    )
    imp.add_argument(
        "--hand-eye",
        type=path_arg,
        metavar="FILE",
        help="X_FC from a static transform YAML (`scanner export --format ros-tf`, "
        "easy_handeye or easy_handeye2, eye-in-hand) (default: none, the camera tool's "
        "nominal mount)",
    )
    imp.add_argument(
        "--image-size",
        type=image_size_arg,
        metavar="WxH",
        help="opencv: image size in pixels when intrinsics.yml has none (stereo_calib's) "
        "(default: none, the size intrinsics.yml gives)",
    )
    imp.add_argument(
        "--length-unit",
        type=name_arg,
        metavar="UNIT",
        help="opencv: unit of T when extrinsics.yml names none: m, cm, mm, or the board "
        "square size (as stereo_calib calibrates in squares): a number in metres, or with a "
        "unit such as 25mm (default m)",
    )


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _require_only(args: argparse.Namespace, names: tuple[str, ...], fmt: str) -> None:
    """Options of one format are refused with the others (rather than silently ignored)."""
    for name in names:
        if getattr(args, name) is not None:
            raise ScannerError(f"{_flag(name)} applies only to --format {fmt}")


def _choose_format(text: str, formats: tuple[str, ...]) -> str:
    if text not in formats:
        raise ScannerError(f"--format: unknown format '{text}'; one of {', '.join(formats)}")
    return text


def _write_files(out: Path, write, names: tuple[str, ...], force: bool) -> list[Path]:
    """`write(folder)` into a hidden folder in `out`, then each file renamed into `out`: a run
    that fails half-way leaves no half-written file; files already there are refused unless
    `force`."""
    from scanner.scan_dir.results_folder import storage_error

    existing = [n for n in names if (out / n).exists()]
    if existing and not force:
        raise ScannerError(
            f"--out {out}: holds {', '.join(existing)} already; choose another --out, or "
            "--force to replace them"
        )
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".export-", dir=out))
    except OSError as e:
        raise storage_error(out, e) from None
    paths = []
    try:
        for path in write(staging):
            os.replace(path, out / path.name)
            paths.append(out / path.name)
        return paths
    except OSError as e:
        raise storage_error(out, e) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        if created and not paths:
            with suppress(OSError):
                out.rmdir()


def run_export(args: argparse.Namespace) -> int:
    from reconstruction.calibration import exchange
    from reconstruction.calibration.file import load_calibration

    fmt = _choose_format(args.format, EXPORT_FORMATS)
    tf = None
    if fmt == "ros-tf":
        # The frame names are checked before the calibration is read (the transform is
        # rebuilt with the real X_FC below).
        parent = args.parent_frame or "tool0"
        child = args.child_frame or "camera_optical_frame"
        for_flag("--parent-frame", lambda: exchange.require_ros_frame(parent, "parent frame"))
        for_flag("--child-frame", lambda: exchange.require_ros_frame(child, "child frame"))
        if parent == child:
            raise ScannerError(f"--parent-frame and --child-frame are both '{parent}'")
    else:
        _require_only(args, TF_ONLY, "ros-tf")
    calibration = load_calibration(args.calibration)
    if fmt == "ros-tf":
        tf = exchange.static_transform(calibration.X_FC, parent, child)
        paths = _write_files(
            args.out,
            lambda folder: exchange.write_static_transform(tf, folder),
            (exchange.HAND_EYE_TF,),
            args.force,
        )
    else:
        if calibration.stereo is None:
            raise ScannerError(
                f"{args.calibration}: holds one camera, --format {fmt} writes a stereo pair "
                "(--format ros-tf writes its hand-eye transform)"
            )
        stereo = calibration.stereo
        if fmt == "opencv":
            write, names = exchange.write_opencv_stereo, exchange.OPENCV_FILES
        else:
            write, names = exchange.write_ros_camera_info, exchange.ROS_FILES
        paths = _write_files(args.out, lambda folder: write(stereo, folder), names, args.force)
    print(f"export ({fmt}): {', '.join(str(p) for p in paths)}")
    if fmt == "opencv":
        print("T, P2 and Q are in metres (length_unit: m in extrinsics.yml)")
    if tf is not None:
        print(f"ROS 1: {tf.ros1_command()}")
        print(f"ROS 2: {tf.ros2_command()}")
    return 0


NOT_MEASURED = "not measured"


def imported_quality(source: str, hand_eye: str) -> dict:
    """The `quality:` of an imported calibration: what a calibration measures (reprojection,
    stereo RMS, board scatter) was not measured here, and the record says so."""
    return {
        "reprojection_rms_px": NOT_MEASURED,
        "stereo_rms_px": NOT_MEASURED,
        "board_scatter_m": NOT_MEASURED,
        "stereo": f"{NOT_MEASURED}: {source}",
        "hand_eye": f"{NOT_MEASURED}: {hand_eye}",
    }


def run_import(args: argparse.Namespace) -> int:
    from reconstruction.calibration import exchange
    from reconstruction.calibration.file import Calibration, save_calibration
    from reconstruction.calibration.plausibility import require_plausible
    from robots.models.camera_tool import nominal_X_FC
    from scanner.scan_dir.results_folder import require_new_file, storage_error

    fmt = _choose_format(args.format, IMPORT_FORMATS)
    unit_m = None
    if fmt == "opencv":
        if args.length_unit is not None:
            unit_m = for_flag("--length-unit", lambda: exchange.parse_length_unit(args.length_unit))
    else:
        _require_only(args, OPENCV_ONLY, "opencv")
    require_new_file(args.out_file, "--out", args.force)
    if fmt == "opencv":
        stereo = exchange.read_opencv_stereo(args.folder, args.image_size, unit_m)
    else:
        stereo = exchange.read_ros_camera_info(args.folder)
    if args.hand_eye is not None:
        X_FC = exchange.read_hand_eye(args.hand_eye)
        hand_eye = f"X_FC from {args.hand_eye}"
    else:
        X_FC = nominal_X_FC(stereo.baseline_m)
        hand_eye = "X_FC nominal (camera tool mount)"
    source = f"imported from {fmt} files in {args.folder}"
    calibration = Calibration(
        X_FC,
        stereo,
        stereo.left,
        source=f"{source}; {hand_eye}",
        created=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        quality=imported_quality(source, hand_eye),
    )
    # Held to the limits a computed calibration is refused at, before anything is written.
    unit = "--length-unit" if fmt == "opencv" else "the files' units"
    require_plausible(
        calibration, str(args.folder), f"{unit} (T read in the wrong unit), or --hand-eye"
    )
    try:
        args.out_file.parent.mkdir(parents=True, exist_ok=True)
        path = save_calibration(calibration, args.out_file)
    except OSError as e:
        raise storage_error(args.out_file, e) from None
    w, h = stereo.image_size
    print(
        f"import ({fmt}): {w}x{h} px, baseline {stereo.baseline_m:.6f} m, "
        f"focal {stereo.left.focal_px:.2f} px; {hand_eye}"
    )
    if args.hand_eye is None:
        print("no --hand-eye given: calibrate X_FC (scanner calibrate) before measuring with it")
    print(f"calibration file: {path}")
    return 0

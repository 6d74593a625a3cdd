"""The command-line arguments of `scanner calibrate` (kept free of heavy imports: the parser is
built for every command)."""

from __future__ import annotations

import argparse

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
    name_arg,
    path_arg,
)

# Where the flags take their defaults from when neither they nor --config give a value.
CALIBRATE_CONFIG = "scanner.calibrate.config:CalibrateConfig"
POSE_FORMAT = "reconstruction.calibration.pose_files:PoseFormat"


def _board_size(board) -> str:
    return f"{board.cols}x{board.rows}"


def add_calibrate_parser(sub) -> None:
    calibrate = add_command(
        sub,
        "calibrate",
        "scanner.commands.calibrate:run_calibrate_command",
        help="calibrate the stereo camera and the hand-eye transform X_FC",
        description="Move the camera around a calibration board, calibrate the stereo pair and "
        "the hand-eye transform, and write a calibration file that scan/reconstruct use "
        "(DIR/results/calibration.yaml). --offline DIR calibrates from recorded images and "
        "robot poses instead; --eye-to-hand calibrates a static camera against the robot.",
    )
    _add_run_arguments(calibrate)
    _add_board_arguments(calibrate)
    _add_offline_arguments(calibrate)
    _add_eye_to_hand_arguments(calibrate)


def _add_run_arguments(calibrate: argparse.ArgumentParser) -> None:
    # Names are validated by the calibration code (one-line errors listing the valid ones), so
    # no argparse `choices` here.
    add_output_arguments(
        calibrate,
        "calibration directory (default calibrations/calib-TIMESTAMP, with --eye-to-hand "
        "calibrations/eye-to-hand-TIMESTAMP; with --offline the recorded directory itself, or "
        "calibrations/NAME-TIMESTAMP for another system's images)",
        "replace an existing --out",
    )
    add_config_file_argument(
        calibrate,
        "calibration YAML file; flags given win over it (default: none, the built-in "
        "defaults stated here)",
    )
    calibrate.add_argument(
        "--resume",
        type=path_arg,
        metavar="DIR",
        help="finish an interrupted eye-in-hand run: capture the stations it lacks, then solve "
        "(default: none, start a new run)",
    )
    add_seed_argument(calibrate)
    add_config_option(
        calibrate,
        "--stations",
        type=int,
        help="number of board views to take (default %(config_default)s)",
        config=ConfigDefault(CALIBRATE_CONFIG, "stations.count"),
    )
    add_config_option(
        calibrate,
        "--sensor",
        type=name_arg,
        help="what the tool carries: stereo (the pair) or rgbd (a depth camera: its colour "
        "images find the board, its depth gives a depth-scale correction) "
        "(default %(config_default)s)",
        config=ConfigDefault(CALIBRATE_CONFIG, "sensor"),
    )
    add_config_option(
        calibrate,
        "--robot",
        type=name_arg,
        metavar="ARM",
        help="the arm: rx60 (the Staubli RX60) or the path of an arm file "
        "(default %(config_default)s)",
        config=ConfigDefault(CALIBRATE_CONFIG, "robot"),
    )
    calibrate.add_argument(
        "--robot-offsets",
        action="store_true",
        help="also estimate the arm's own errors with X_FC: the joints' zero offsets and the "
        "link lengths the poses make observable (needs recorded joint angles: live runs and "
        "their capture folders); kept, written to the calibration file and used by scans only "
        "when they predict held-out views better (default: off)",
    )
    add_driver_argument(
        calibrate, "eye-in-hand", "; the board stands where the configuration's placement says"
    )


def _add_board_arguments(calibrate: argparse.ArgumentParser) -> None:
    board = calibrate.add_argument_group(
        "board (defaults: the configuration's board; with --offline, the board a calibration "
        "directory recorded, else --board, --board-size and --board-spacing are needed)"
    )
    add_config_option(
        board,
        "--board",
        type=name_arg,
        help="charuco, chessboard or circles_asymmetric (default %(config_default)s)",
        config=ConfigDefault(CALIBRATE_CONFIG, "board.kind"),
    )
    add_config_option(
        board,
        "--board-size",
        type=name_arg,
        metavar="COLSxROWS",
        help="squares (chessboard, charuco) or circles (circle grid) across x down, e.g. 7x11 "
        "(default %(config_default)s)",
        config=ConfigDefault(CALIBRATE_CONFIG, "board", _board_size),
    )
    add_config_option(
        board,
        "--board-spacing",
        action=LengthOption,
        help=f"square size, or circle distance along a row; {LENGTH_HELP} (default "
        "%(config_default)s m)",
        config=ConfigDefault(CALIBRATE_CONFIG, "board.spacing_m"),
    )
    add_config_option(
        board,
        "--marker-size",
        action=LengthOption,
        help=f"ChArUco marker size; {LENGTH_HELP} (default %(config_default)s m; with --offline "
        "0.75 x --board-spacing)",
        config=ConfigDefault(CALIBRATE_CONFIG, "board.marker_m"),
    )
    add_config_option(
        board,
        "--dictionary",
        type=name_arg,
        help="ArUco dictionary, e.g. DICT_4X4_50 (default %(config_default)s)",
        config=ConfigDefault(CALIBRATE_CONFIG, "board.dictionary"),
    )
    board.add_argument(
        "--inverted",
        action="store_true",
        help="white pattern on black, e.g. white dots (default: off)",
    )


def _add_offline_arguments(calibrate: argparse.ArgumentParser) -> None:
    offline = calibrate.add_argument_group("offline calibration from recorded data")
    offline.add_argument(
        "--offline",
        type=path_arg,
        metavar="DIR",
        help="a calibration directory made by this tool, or images with robot pose files "
        "(same name, .txt) or left/ and right/ image folders; with --eye-to-hand, the folder "
        "an --eye-to-hand run recorded, solved again (default: none, move the robot "
        "in the simulator or with --driver)",
    )
    offline.add_argument(
        "--pose-convention",
        type=name_arg,
        help="robot pose preset: open3dv, yaskawa, fanuc, kuka, staubli, abb, ur, matrix_m, "
        "matrix_mm (default: none, the layout, sequence and units below)",
    )
    add_config_option(
        offline,
        "--pose-layout",
        type=name_arg,
        help="matrix, xyz_euler, euler_xyz, xyz_quat, xyz_wxyz or xyz_rotvec "
        "(default %(config_default)s, or the --pose-convention's)",
        config=ConfigDefault(POSE_FORMAT, "layout"),
    )
    add_config_option(
        offline,
        "--euler",
        type=name_arg,
        help="Euler sequence: xyz (extrinsic) ... XYZ (intrinsic) "
        "(default %(config_default)s, or the --pose-convention's)",
        config=ConfigDefault(POSE_FORMAT, "euler"),
    )
    add_config_option(
        offline,
        "--length-unit",
        type=name_arg,
        help="m or mm (default %(config_default)s, or the --pose-convention's)",
        config=ConfigDefault(POSE_FORMAT, "length_unit"),
    )
    add_config_option(
        offline,
        "--angle-unit",
        type=name_arg,
        help="deg or rad (default %(config_default)s, or the --pose-convention's)",
        config=ConfigDefault(POSE_FORMAT, "angle_unit"),
    )
    offline.add_argument(
        "--inverse-poses",
        action="store_true",
        help="the files hold the base in the flange (default: off, the flange in the base)",
    )
    offline.add_argument(
        "--pose-file",
        type=path_arg,
        help="one pose per line, in image name order (default: none, a NAME.txt beside each image)",
    )
    offline.add_argument(
        "--intrinsics",
        type=path_arg,
        help="known intrinsics: calibration/stereo YAML, or text (K row by row, k1 k2 p1 p2 k3) "
        "(default: none, estimated from the images)",
    )


def _add_eye_to_hand_arguments(calibrate: argparse.ArgumentParser) -> None:
    e2h = calibrate.add_argument_group("eye-to-hand (static camera, marker on the flange)")
    e2h.add_argument(
        "--eye-to-hand",
        action="store_true",
        help="calibrate a static camera (default: off, the wrist camera)",
    )
    add_config_option(
        e2h,
        "--held-out",
        type=int,
        help="random test points (default %(config_default)s)",
        config=ConfigDefault(CALIBRATE_CONFIG, "eye_to_hand.held_out"),
    )
    add_config_option(
        e2h,
        "--grid-spacing",
        action=LengthOption,
        help=f"spacing of the calibration grid; {LENGTH_HELP} (default %(config_default)s m)",
        config=ConfigDefault(CALIBRATE_CONFIG, "eye_to_hand.grid_spacing_m"),
    )

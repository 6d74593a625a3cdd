"""The command-line arguments of `scanner calibrate` (kept free of heavy imports: the parser is
built for every command)."""

from __future__ import annotations

import argparse

from scanner.arguments import (
    add_driver_argument,
    add_output_arguments,
    add_seed_argument,
    name_arg,
    path_arg,
    positive_float,
)


def add_calibrate_parser(sub) -> None:
    calibrate = sub.add_parser(
        "calibrate",
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
    add_output_arguments(calibrate, "calibration directory", "replace an existing --out")
    calibrate.add_argument("--config", type=path_arg, help="calibration YAML file")
    calibrate.add_argument(
        "--resume",
        type=path_arg,
        metavar="DIR",
        help="finish an interrupted eye-in-hand run: capture the stations it lacks, then solve",
    )
    add_seed_argument(calibrate)
    calibrate.add_argument(
        "--stations", type=int, help="number of board views to take (default 20)"
    )
    add_driver_argument(
        calibrate, "eye-in-hand", "; the board stands where the configuration's placement says"
    )


def _add_board_arguments(calibrate: argparse.ArgumentParser) -> None:
    board = calibrate.add_argument_group("board (simulation default: chessboard 10x7, 0.02 m)")
    board.add_argument("--board", type=name_arg, help="charuco, chessboard or circles_asymmetric")
    board.add_argument(
        "--board-size",
        type=name_arg,
        metavar="COLSxROWS",
        help="squares (chessboard, charuco) or circles (circle grid) across x down, e.g. 7x11",
    )
    board.add_argument(
        "--board-spacing",
        type=positive_float,
        metavar="M",
        help="square size, or circle distance along a row, in metres",
    )
    board.add_argument(
        "--marker-size",
        type=positive_float,
        metavar="M",
        help="ChArUco marker size in metres",
    )
    board.add_argument("--dictionary", type=name_arg, help="ArUco dictionary, e.g. DICT_5X5_100")
    board.add_argument(
        "--inverted", action="store_true", help="white pattern on black (e.g. white dots)"
    )


def _add_offline_arguments(calibrate: argparse.ArgumentParser) -> None:
    offline = calibrate.add_argument_group("offline calibration from recorded data")
    offline.add_argument(
        "--offline",
        type=path_arg,
        metavar="DIR",
        help="a calibration directory made by this tool, or images with robot pose files "
        "(same name, .txt) or left/ and right/ image folders",
    )
    offline.add_argument(
        "--pose-convention",
        type=name_arg,
        help="robot pose preset: open3dv, yaskawa, fanuc, kuka, staubli, abb, ur, matrix_m, "
        "matrix_mm",
    )
    offline.add_argument(
        "--pose-layout",
        type=name_arg,
        help="matrix, xyz_euler, euler_xyz, xyz_quat, xyz_wxyz or xyz_rotvec",
    )
    offline.add_argument(
        "--euler", type=name_arg, help="Euler sequence: xyz (extrinsic) ... XYZ (intrinsic)"
    )
    offline.add_argument("--length-unit", type=name_arg, help="m or mm")
    offline.add_argument("--angle-unit", type=name_arg, help="deg or rad")
    offline.add_argument(
        "--inverse-poses", action="store_true", help="the files hold the base in the flange"
    )
    offline.add_argument(
        "--pose-file", type=path_arg, help="one pose per line, in image name order"
    )
    offline.add_argument(
        "--intrinsics",
        type=path_arg,
        help="known intrinsics: calibration/stereo YAML, or text (K row by row, k1 k2 p1 p2 k3)",
    )


def _add_eye_to_hand_arguments(calibrate: argparse.ArgumentParser) -> None:
    e2h = calibrate.add_argument_group("eye-to-hand (static camera, marker on the flange)")
    e2h.add_argument("--eye-to-hand", action="store_true", help="calibrate a static camera")
    e2h.add_argument("--held-out", type=int, help="random test points (default 100)")
    e2h.add_argument("--grid-spacing", type=positive_float, metavar="M", help="grid spacing (m)")

"""The calibration solver on board observations: intrinsics (unless given), stereo when there
are right images, then hand-eye; the result as the calibration file's record."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.eye_in_hand import (
    HandEyeCalibration,
    calibrate_hand_eye,
    require_poses,
)
from reconstruction.calibration.file import Calibration, RobotCorrection
from reconstruction.calibration.intrinsics import (
    StereoCalibration,
    calibrate_camera,
    calibrate_stereo,
)
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera
from scanner.configs.typed_yaml import to_dict


def no_board_anywhere(board: BoardSpec, observations) -> str:
    """The advice when no image shows the board: its description is wrong, not the poses few."""
    example = next((o for o in observations if o.not_found), observations[0])
    polarity = "white on black (--inverted given)" if board.inverted else "black on white"
    return (
        f"the board ({board.kind}, {board.cols}x{board.rows}, {polarity}) was not found in any "
        f"of the {len(observations)} images ({example.name}: {example.not_found or 'not found'}"
        "): more poses will not help; check --board-size (counted in squares, not inner "
        "corners; circles for a circle grid), --inverted (a white pattern on black) and "
        "--board / --board-spacing"
    )


def x_fc_sigma_record(sigma) -> dict:
    """X_FC's standard deviations for files (SI): rotation about and translation along the
    camera frame C's axes, X_FC_true = X_FC @ twist_to_pose(rotation, translation)."""
    return {
        "rotation_rad": [float(v) for v in sigma[:3]],
        "translation_m": [float(v) for v in sigma[3:]],
        "frame": "C",
    }


@dataclass(frozen=True, eq=False)
class Solution:
    """What one calibration produced (before it is written)."""

    calibration: Calibration
    hand_eye: HandEyeCalibration
    stereo: StereoCalibration | None
    camera_rms_px: float | None  # mono: calibrateCamera RMS; None when intrinsics were given
    observations: tuple[PoseObservation, ...]
    solve_s: float


@dataclass(frozen=True, eq=False)
class CalibrationRun:
    out_dir: Path  # the calibration (or foreign data's output) directory
    results_dir: Path  # where this run's calibration.yaml and reports are
    calibration_file: Path
    report: dict
    solution: Solution


def solve(
    board: BoardSpec,
    observations: list[PoseObservation],
    image_size: tuple[int, int],
    settings: CalibrationSettings,
    intrinsics: StereoCamera | PinholeCamera | None = None,
    source: str = "offline",
    robot: str = "rx60",
) -> Solution:
    """Intrinsics (unless given), then hand-eye; stereo when any pose has a right image.
    `robot`: the arm that made the poses (as a configuration's `robot`), whose own errors
    `settings.robot_offsets` estimates."""
    t0 = time.perf_counter()
    is_stereo = any(o.right is not None for o in observations)
    found = [o for o in observations if o.left is not None]
    missing = [
        f"{o.name} ({o.not_found})" if o.not_found else o.name
        for o in observations
        if o.left is None
    ]
    if observations and not found:
        raise ScannerError(no_board_anywhere(board, observations))
    require_poses(len(found), len(observations), missing, settings.min_poses)
    stereo_cal, camera_rms = None, None
    if intrinsics is None:
        if is_stereo:
            stereo_cal = calibrate_stereo(board, observations, image_size, settings)
            cameras: StereoCamera | PinholeCamera = stereo_cal.stereo
        else:
            mono = calibrate_camera(board, [o.left for o in found], image_size, settings)
            cameras, camera_rms = mono.camera, mono.rms_px
    else:
        if is_stereo and not isinstance(intrinsics, StereoCamera):
            raise ScannerError("stereo data needs stereo intrinsics (a stereo camera file)")
        cameras = intrinsics
        if not is_stereo and isinstance(intrinsics, StereoCamera):
            cameras = intrinsics.left
        size = cameras.left if isinstance(cameras, StereoCamera) else cameras
        if (size.width, size.height) != tuple(image_size):
            raise ScannerError(
                f"the intrinsics are for {size.width}x{size.height} images, the images are "
                f"{image_size[0]}x{image_size[1]}"
            )
    arm = None
    if settings.robot_offsets:
        from robots.arms.default import arm_of

        arm = arm_of(robot).error_model()
    hand_eye = calibrate_hand_eye(
        board, observations, cameras, settings, arm=arm, robot_offsets=settings.robot_offsets
    )
    quality = {
        "reprojection_rms_px": hand_eye.rms_px,
        "reprojection_rms_after_robot_corrections_px": hand_eye.corrected_rms_px,
        "stereo_rms_px": None if stereo_cal is None else stereo_cal.rms_px,
        "poses_used": len(hand_eye.used),
        "poses_outliers": hand_eye.outliers,
        "poses_board_not_found": hand_eye.not_found,
        "board_scatter_m": hand_eye.board_scatter_m.tolist(),
        "hand_eye_seed": hand_eye.seed_method,
        "X_FC_sigma": x_fc_sigma_record(hand_eye.X_FC_sigma),
    }
    if hand_eye.quality is not None:
        quality["held_out_rms_px"] = hand_eye.quality.held_out.rms_px
        quality["held_out_rms_m"] = hand_eye.quality.held_out.rms_m
    robot = None
    if hand_eye.robot_errors is not None and hand_eye.robot_errors.kept:
        e = hand_eye.robot_errors
        robot = RobotCorrection(tuple(e.joint_offsets_rad), e.link_length_corrections_m, e.arm_name)
    calibration = Calibration(
        hand_eye.X_FC,
        cameras if isinstance(cameras, StereoCamera) else None,
        cameras.left if isinstance(cameras, StereoCamera) else cameras,
        source,
        "",
        hand_eye.X_WB,
        to_dict(board),
        quality,
        robot=robot,
    )
    return Solution(
        calibration,
        hand_eye,
        stereo_cal,
        camera_rms,
        tuple(observations),
        time.perf_counter() - t0,
    )

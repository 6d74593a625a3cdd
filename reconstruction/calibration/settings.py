"""Thresholds of the calibration (the `solver:` section of a calibration configuration)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from reconstruction.common.checks import require_count, require_non_negative, require_positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.robust_loss import check_loss


@dataclass(frozen=True)
class CalibrationSettings:
    """Thresholds of the calibration (units in the names).

    min_poses: hand-eye needs 3 poses (two motions about different axes); two more let the
        outlier test compare each pose with the others.
    min_motion_rotation_rad: relative rotations below this carry too little hand-eye information.
    min_axis_spread_rad: the motions' rotation axes must differ by at least this much, otherwise
        the translation along the common axis is unobservable (Tsai & Lenz 1989).
    pixel_sigma_px: standard deviation of a detected board point (px per coordinate), including
        model error, for the refinements that decide the outliers.
    pixel_sigma_from_data: the final refinement uses instead the spread of the board points once
        every pose has its robot correction (what the images alone leave), at least
        min_pixel_sigma_px (which keeps the weights finite on noise-free synthetic data; corner
        and circle detectors reach ~0.02 px at best).
    robot_translation_sigma_m, robot_rotation_sigma_rad: accuracy of the reported flange poses
        (0 and 0: trust them exactly). Defaults: a calibrated 6-axis arm of the RX60's class.
    min_robot_translation_sigma_m, min_robot_rotation_sigma_rad: the arm's repeatability (the
        RX60: +-0.02 mm): what is left of a pose's error once its systematic errors are
        modelled (--robot-offsets) is never taken smaller.
    robust_loss, robust_scale: scipy least_squares loss and its scale in sigmas.
    outlier_factor, outlier_min_px: a pose is an outlier when its RMS reprojection error exceeds
        both factor x the median pose RMS and min_px.
    fix_k3: estimate only k1, k2, p1, p2 (fewer parameters for short focal-range data).
    held_out_folds: views are held out in this many folds to measure prediction on views the
        fit did not see (leave-one-out below 6 views).
    bootstrap_samples: refits on views drawn with replacement for X_FC's uncertainty.
    robot_offsets: also estimate the arm's own errors (joint zero offsets, link lengths) where
        the poses make them observable, kept only when they predict held-out views better.
    offset_min_independence: such a parameter is estimated only when the image change it makes
        is at least this independent (sine of the angle) of what X_FC, the board pose and the
        other parameters can do.
    max_reprojection_rms_px, max_board_scatter_m, max_hand_eye_translation_m, max_baseline_m:
        a calibration beyond any of these is refused as physically implausible (a wrong pose
        convention gives hundreds of px, tens of cm of board scatter and metres of X_FC; a
        wrong length unit scales the baseline and X_FC alike; real sets of usable quality stay
        within a few px and mm, a wrist camera and its stereo pair within a tool's size).
    """

    min_poses: int = 5
    min_points_per_view: int = 6
    min_motion_rotation_rad: float = math.radians(2.0)
    min_axis_spread_rad: float = math.radians(10.0)
    pixel_sigma_px: float = 0.3
    pixel_sigma_from_data: bool = True
    min_pixel_sigma_px: float = 0.01
    robot_translation_sigma_m: float = 0.0002
    robot_rotation_sigma_rad: float = math.radians(0.02)
    min_robot_translation_sigma_m: float = 1e-5
    min_robot_rotation_sigma_rad: float = math.radians(0.001)
    robust_loss: str = "soft_l1"
    robust_scale: float = 3.0
    outlier_factor: float = 4.0
    outlier_min_px: float = 1.0
    fix_k3: bool = False
    held_out_folds: int = 5
    bootstrap_samples: int = 200
    robot_offsets: bool = False
    offset_min_independence: float = 0.05
    max_reprojection_rms_px: float = 10.0
    max_board_scatter_m: float = 0.02
    max_hand_eye_translation_m: float = 0.5
    max_baseline_m: float = 0.5

    def __post_init__(self) -> None:
        if self.min_poses < 3:
            raise ScannerError(
                f"solver.min_poses: must be at least 3 (hand-eye needs 3), got {self.min_poses}"
            )
        require_count("solver", self, ("min_points_per_view",), minimum=4)
        require_count("solver", self, ("held_out_folds",), minimum=2)
        require_count("solver", self, ("bootstrap_samples",), minimum=10)
        check_loss(self.robust_loss, "solver.robust_loss")
        require_positive(
            "solver",
            self,
            (
                "pixel_sigma_px",
                "min_pixel_sigma_px",
                "robust_scale",
                "outlier_factor",
                "outlier_min_px",
                "max_reprojection_rms_px",
                "max_board_scatter_m",
                "max_hand_eye_translation_m",
                "max_baseline_m",
                "offset_min_independence",
                "min_robot_translation_sigma_m",
                "min_robot_rotation_sigma_rad",
                "min_motion_rotation_rad",
                "min_axis_spread_rad",
            ),
        )
        require_non_negative(
            "solver", self, ("robot_translation_sigma_m", "robot_rotation_sigma_rad")
        )

"""Hand-eye (eye-in-hand) calibration from robot poses and board detections. Pure numeric.

Frames: W robot base, F flange, C left optical frame, R right optical frame, B board. The robot
reports X_WF for every pose; PnP gives X_CB (OpenCV's solvePnP returns the board in the camera);
the board is fixed in W, so X_WB = X_WF_i @ X_FC @ X_CB_i for every pose i.

Pipeline (`calibrate_hand_eye`):
1. board pose per robot pose by PnP (intrinsics from the stereo/mono calibration or given);
2. refuse too few poses or degenerate motions (rotations about one axis only), saying why;
3. X_FC by each of OpenCV's five AX = XB methods; the one that reprojects best seeds step 4;
4. joint non-linear refinement of X_FC and X_WB minimising the reprojection error of every board
   point in every camera (left and, for a stereo rig, right through X_RC) with a robust loss;
5. per-pose residuals; the worst pose is dropped while it is an outlier (RMS above
   `outlier_factor` x the median and above `outlier_min_px`), and step 4 is repeated;
6. the pixel noise is measured on the inliers and step 4 is run once more with it (see
   `image_noise_px`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.hand_eye import (
    MotionSummary,
    check_motions,
    solve_every_method,
    solve_hand_eye,
)
from reconstruction.calibration.held_out import make_folds
from reconstruction.calibration.observations import PoseObservation, board_pose
from reconstruction.calibration.quality import CalibrationQuality, assess, combined_sigma
from reconstruction.calibration.refine import (
    Refinement,
    pose_rms,
    refine_on_board,
    reprojection_residuals,
    sensor_points,
)
from reconstruction.calibration.robot_errors import ArmModel, RobotErrors, estimate
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import mean_pose, skew
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera


@dataclass(frozen=True, eq=False)
class PoseResidual:
    """One pose's outcome: RMS reprojection error (px) under the final X_FC and X_WB (NaN when
    the board was not found) and its status: "used", "outlier" or "board not found"."""

    name: str
    rms_px: float
    status: str


@dataclass(frozen=True, eq=False)
class HandEyeCalibration:
    """Result of `calibrate_hand_eye`.

    X_FC: refined hand-eye pose (left camera in flange); X_WB: refined board pose in the base.
    opencv: X_FC of each OpenCV method alone, on the poses finally used; seed_method: the one
    that seeded the refinement. board_scatter_m: per-axis standard deviation (m) of the board
    origin mapped into W through each used pose (X_WF_i X_FC X_CB_i): the self-consistency a
    user can check without ground truth. rms_px: reprojection RMS of the used poses with the
    robot poses as reported; corrected_rms_px: after the small robot-pose corrections the
    estimate implies (robot_corrections, (6,) per used pose: rotation vector rad, translation m).
    pixel_sigma_px: the board point standard deviation (px, per coordinate) the final refinement
    weighted the images with (see `image_noise_px`). X_FC_sigma: see the field.
    """

    X_FC: np.ndarray
    X_WB: np.ndarray
    rms_px: float
    corrected_rms_px: float
    opencv: dict[str, np.ndarray]
    seed_method: str
    residuals: tuple[PoseResidual, ...]
    board_scatter_m: np.ndarray
    board_scatter_max_m: float
    motion: MotionSummary
    X_CB: dict[str, np.ndarray] = field(default_factory=dict)
    robot_corrections: dict[str, np.ndarray] = field(default_factory=dict)
    opencv_failed: dict[str, str] = field(default_factory=dict)
    pixel_sigma_px: float = math.nan
    # (6, 6) covariance of X_FC: rotation vector (rad) then translation (m), in the camera frame
    # C (X_FC_true = X_FC @ twist_to_pose(delta)); see `hand_eye_covariance`.
    X_FC_covariance: np.ndarray = field(default_factory=lambda: np.full((6, 6), np.nan))
    # Held-out prediction, bootstrap and the methods' agreement (None: not assessed).
    quality: CalibrationQuality | None = None
    # --robot-offsets' outcome (None: not asked); its parameters are in use when it says kept.
    robot_errors: RobotErrors | None = None

    @property
    def X_FC_sigma(self) -> np.ndarray:
        """(6,) standard deviations: rotation (rad) about C's x y z, translation (m) along them;
        per axis the larger of the covariance's and the bootstrap's (`quality.combined_sigma`)."""
        if self.quality is not None:
            q = self.quality
            return combined_sigma(self.X_FC_covariance, q.bootstrap_sigma, q.common_sigma)
        return np.sqrt(np.clip(np.diag(self.X_FC_covariance), 0.0, None))

    @property
    def X_FC_covariance_sigma(self) -> np.ndarray:
        """(6,) the covariance's standard deviations alone."""
        return np.sqrt(np.clip(np.diag(self.X_FC_covariance), 0.0, None))

    @property
    def robot_params(self) -> np.ndarray | None:
        """The arm's error parameters in use (`robot_errors.ArmModel`); None when none are."""
        if self.robot_errors is None or not self.robot_errors.kept:
            return None
        return self.robot_errors.params

    @property
    def used(self) -> list[str]:
        return [r.name for r in self.residuals if r.status == "used"]

    @property
    def outliers(self) -> list[str]:
        return [r.name for r in self.residuals if r.status == "outlier"]

    @property
    def not_found(self) -> list[str]:
        return [r.name for r in self.residuals if r.status == "board not found"]


def _left_camera(cameras: StereoCamera | PinholeCamera) -> PinholeCamera:
    return cameras.left if isinstance(cameras, StereoCamera) else cameras


def require_poses(usable: int, total: int, missing: Sequence[str], need: int) -> None:
    """ScannerError saying how many more poses to record, and why, when usable < need."""
    if usable >= need:
        return
    if usable == 0 and total > 0:
        # Nothing found anywhere is a description problem, not a shortage of poses.
        example = f" ({missing[0]})" if missing else ""
        raise ScannerError(
            f"the board was not found in any of the {total} images{example}: check the board's "
            "size, counted in squares (not inner corners), and its polarity (white pattern on "
            "black, or black on white) before recording more poses"
        )
    why = f"; the board was not found in: {', '.join(missing)}" if missing else ""
    raise ScannerError(
        f"only {usable} of {total} poses are usable, calibration needs at least {need} (hand-eye "
        f"needs 3, the outlier test {need - 3} more): record {need - usable} more pose(s) with "
        f"the whole board in view{why}"
    )


def board_scatter(
    X_WF: Sequence[np.ndarray], X_FC: np.ndarray, X_CB: Sequence[np.ndarray]
) -> tuple[np.ndarray, float]:
    """Per-axis std (m) and the largest distance from the mean (m) of the board origins in W."""
    p = np.array([(Xf @ X_FC @ Xc)[:3, 3] for Xf, Xc in zip(X_WF, X_CB)])
    return p.std(axis=0), float(np.linalg.norm(p - p.mean(axis=0), axis=1).max())


def robot_corrections_enabled(settings: CalibrationSettings) -> bool:
    """Whether the refinement estimates a correction of every reported flange pose."""
    return settings.robot_translation_sigma_m > 0 and settings.robot_rotation_sigma_rad > 0


def image_noise_px(
    board: BoardSpec,
    inliers: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    refined: Refinement,
    settings: CalibrationSettings,
) -> float:
    """Standard deviation (px, per image coordinate) of the board points about the model once
    every pose has its robot correction, at least `min_pixel_sigma_px`.

    Why the final refinement weighs the images with this rather than the configured
    `pixel_sigma_px`: the refinement balances the images against the robot-pose prior, and
    with a free correction per pose the images leave only detection noise and lens-model
    error, which this measures. A sigma ten times too large (0.3 px configured, 0.02-0.03 px
    measured on the simulated chessboard and on a real circle grid) weighs the images a hundred
    times too little; along what one view measures weakly (distance, tilt traded against sideways
    shift) the prior then pulls each correction to zero and that pose's robot error goes into
    the shared X_FC: 0.22 mm instead of 0.11 mm on one simulated set, and on average worse
    than OpenCV's Tsai alone. The seed and the outlier test were not the cause: seeded from
    any method the refinement reaches the same X_FC, and no simulated pose was an outlier.
    """
    sensors = sensor_points(board, inliers, cameras)
    points = sum(len(s.pose_index) for s in sensors)
    parameters = 12 + (6 * len(inliers) if robot_corrections_enabled(settings) else 0)
    # corrected_rms_px is per point over both coordinates: the squared sum is rms^2 * points.
    dof = max(2 * points - parameters, 1)
    return max(settings.min_pixel_sigma_px, refined.corrected_rms_px * math.sqrt(points / dof))


def _seed(
    board: BoardSpec,
    obs: list[PoseObservation],
    X_CB: list[np.ndarray],
    cameras: StereoCamera | PinholeCamera,
) -> tuple[dict[str, np.ndarray], str, np.ndarray]:
    """Every OpenCV method; the seed is the one whose X_FC (with the mean board pose it implies)
    reprojects best by the median pose RMS (robust to a few bad poses)."""
    X_WF = [o.X_WF for o in obs]
    sensors = sensor_points(board, obs, cameras)
    estimates, failures = solve_every_method(X_WF, X_CB)
    if not estimates:
        raise ScannerError(
            "hand-eye calibration failed: every OpenCV method failed ("
            + "; ".join(failures.values())
            + ")"
        )
    scores, boards = {}, {}
    for name, X_FC in estimates.items():
        X_WB = mean_pose([Xf @ X_FC @ Xc for Xf, Xc in zip(X_WF, X_CB)])
        residuals = reprojection_residuals(sensors, np.array(X_WF), X_FC, X_WB)
        boards[name] = X_WB
        scores[name] = float(np.median(pose_rms(sensors, residuals, len(obs))))
    best = min(scores, key=scores.get)
    return estimates, best, boards[best]


def calibrate_hand_eye(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    settings: CalibrationSettings = CalibrationSettings(),
    arm: ArmModel | None = None,
    robot_offsets: bool = False,
) -> HandEyeCalibration:
    """X_FC (and X_WB) from robot poses and board detections; see the module docstring.
    `robot_offsets`: also the arm's observable zero offsets and link lengths
    (`robot_errors.estimate`; `arm` is its kinematics, the observations carry their joints)."""
    usable = [
        o
        for o in observations
        if o.left is not None and len(o.left) >= settings.min_points_per_view
    ]
    missing = [o.name for o in observations if o not in usable]
    require_poses(len(usable), len(observations), missing, settings.min_poses)
    left = _left_camera(cameras)
    X_CB = {o.name: board_pose(board, o.left, left) for o in usable}
    motion = check_motions([o.X_WF for o in usable], settings)
    _, seed_method, X_WB = _seed(board, usable, [X_CB[o.name] for o in usable], cameras)
    X_FC = solve_hand_eye([o.X_WF for o in usable], [X_CB[o.name] for o in usable], seed_method)

    inliers = list(usable)
    outliers: list[PoseObservation] = []
    while True:
        refined = refine_on_board(board, inliers, cameras, X_FC, X_WB, settings)
        X_FC, X_WB = refined.X_FC, refined.X_WB
        rms = refined.pose_rms_px
        limit = max(settings.outlier_min_px, settings.outlier_factor * float(np.median(rms)))
        worst = int(np.argmax(rms))
        if rms[worst] <= limit or len(inliers) <= settings.min_poses:
            break
        outliers.append(inliers.pop(worst))
    pixel_sigma = settings.pixel_sigma_px
    # Without robot corrections the residuals hold the robot's errors too and there is no
    # prior for the sigma to balance: the configured one stays.
    if settings.pixel_sigma_from_data and robot_corrections_enabled(settings):
        pixel_sigma = image_noise_px(board, inliers, cameras, refined, settings)
        refined = refine_on_board(
            board, inliers, cameras, X_FC, X_WB, replace(settings, pixel_sigma_px=pixel_sigma)
        )
        X_FC, X_WB = refined.X_FC, refined.X_WB
    final_settings = replace(settings, pixel_sigma_px=pixel_sigma)
    folds = make_folds(len(inliers), settings.held_out_folds)
    errors = None
    if robot_offsets:
        refined, errors = estimate(board, inliers, cameras, refined, final_settings, arm, folds)
        X_FC, X_WB = refined.X_FC, refined.X_WB

    # Final residuals of every pose (outliers too) under the final estimate.
    sensors_all = sensor_points(board, usable, cameras)
    if refined.robot_params is not None:
        X_WF_all = np.array([arm.flange_pose(o.q_rad, refined.robot_params) for o in usable])
    else:
        X_WF_all = np.array([o.X_WF for o in usable])
    rms_all = pose_rms(
        sensors_all, reprojection_residuals(sensors_all, X_WF_all, X_FC, X_WB), len(usable)
    )
    by_name = {o.name: float(r) for o, r in zip(usable, rms_all)}
    residuals = []
    for o in observations:
        if o.name in missing:
            residuals.append(PoseResidual(o.name, float("nan"), "board not found"))
        elif o in outliers:
            residuals.append(PoseResidual(o.name, by_name[o.name], "outlier"))
        else:
            residuals.append(PoseResidual(o.name, by_name[o.name], "used"))
    X_WF_in = [o.X_WF for o in inliers]
    X_CB_in = [X_CB[o.name] for o in inliers]
    opencv, opencv_failed = solve_every_method(X_WF_in, X_CB_in)
    scatter, scatter_max = board_scatter(X_WF_in, X_FC, X_CB_in)
    covariance = hand_eye_covariance(refined.X_FC_covariance, X_FC, settings)
    quality = assess(
        board,
        inliers,
        cameras,
        refined,
        X_CB_in,
        opencv,
        covariance,
        np.diag(common_robot_error_covariance(X_FC, settings)),
        folds,
        settings.bootstrap_samples,
        None if arm is None else arm.flange_pose,
    )
    return HandEyeCalibration(
        X_FC,
        X_WB,
        refined.rms_px,
        refined.corrected_rms_px,
        opencv,
        seed_method,
        tuple(residuals),
        scatter,
        scatter_max,
        motion,
        X_CB,
        {o.name: xi for o, xi in zip(inliers, refined.corrections)},
        opencv_failed,
        pixel_sigma,
        covariance,
        quality,
        errors,
    )


def hand_eye_covariance(
    data_covariance: np.ndarray, X_FC: np.ndarray, settings: CalibrationSettings
) -> np.ndarray:
    """X_FC's covariance (6, 6; rotation rad, translation m, in C): what the data determine plus
    what no hand-eye data can, the part of the robot's error that is the same in every pose.

    A flange error E that is the same in every pose (an encoder zero of the last joint, a
    tool-flange length, a mis-seated adapter) gives X_WF E X_FC = X_WF X_FC' with
    X_FC' = E X_FC: it goes into X_FC whatever the images, and neither the refinement's
    covariance nor resampling the views can see it. Its size is the robot's accuracy
    (solver.robot_rotation_sigma_rad, robot_translation_sigma_m, in the flange frame). Measured
    on the simulator: with only the last joint's zero counted (encoder offsets of 0.01 deg per
    joint) the rotation about the optical axis was off by up to 3.4 of its sigmas in 3 of 10
    calibrations; with link-length errors of 0.5-1 mm, X_FC was off by 2-18 sigmas of the
    covariance and the bootstrap in every one.
    """
    return data_covariance + common_robot_error_covariance(X_FC, settings)


def common_robot_error_covariance(X_FC: np.ndarray, settings: CalibrationSettings) -> np.ndarray:
    """(6, 6) the covariance in C of X_FC' = E X_FC for a flange error E with the robot's
    accuracy (see `hand_eye_covariance`); zero when the robot poses are trusted exactly."""
    if not robot_corrections_enabled(settings):
        return np.zeros((6, 6))
    R_CF = X_FC[:3, :3].T
    p_CF = -R_CF @ X_FC[:3, 3]
    # The adjoint of X_CF maps a flange-frame twist (rotation, translation) into C.
    ad = np.zeros((6, 6))
    ad[:3, :3] = R_CF
    ad[3:, 3:] = R_CF
    ad[3:, :3] = skew(p_CF) @ R_CF
    sigma = np.r_[
        np.full(3, settings.robot_rotation_sigma_rad),
        np.full(3, settings.robot_translation_sigma_m),
    ]
    return ad @ np.diag(sigma**2) @ ad.T

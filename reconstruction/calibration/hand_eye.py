"""X_FC from robot poses and camera poses of a world-fixed target by OpenCV's AX = XB solvers,
and whether the motions can determine it at all.

cv2.calibrateHandEye takes gripper2base = X_WF and target2cam = X_CT for a target T fixed in W
and returns cam2gripper, which is our X_FC. The target is the calibration board (X_CB by PnP) in
`scanner calibrate`, and the pose graph's world frame (X_CT = inv(X_WC_refined)) in the
correction of X_FC from a scan.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, matrix_to_rotvec, rotation_angle_rad

# OpenCV's AX = XB solvers, by the names this product uses in files and on the command line.
HAND_EYE_METHODS: dict[str, int] = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}


def solve_hand_eye(
    X_WF: Sequence[np.ndarray], X_CT: Sequence[np.ndarray], method: str
) -> np.ndarray:
    """X_FC by one of OpenCV's calibrateHandEye methods (gripper = F, base = W, target T fixed
    in W); HandEyeMethodError when the solver fails on these poses."""
    if method not in HAND_EYE_METHODS:
        raise ScannerError(
            f"unknown hand-eye method '{method}'; valid: {', '.join(HAND_EYE_METHODS)}"
        )
    try:
        R, t = cv2.calibrateHandEye(
            [X[:3, :3] for X in X_WF],
            [X[:3, 3] for X in X_WF],
            [X[:3, :3] for X in X_CT],
            [X[:3, 3] for X in X_CT],
            method=HAND_EYE_METHODS[method],
        )
    except cv2.error as e:
        # Andreff's linear system can be singular (e.g. on noise-free data).
        raise HandEyeMethodError(f"OpenCV hand-eye method '{method}' failed: {e.err}") from None
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise HandEyeMethodError(f"OpenCV hand-eye method '{method}' gave a non-finite result")
    # On motions that fit no rigid X (e.g. a wrong pose convention) some methods return a
    # matrix that is not a rotation; OpenCV only logs that.
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise HandEyeMethodError(
            f"OpenCV hand-eye method '{method}' found no rotation that fits these motions"
        )
    return make_pose(R, t)


class HandEyeMethodError(ScannerError):
    """One OpenCV AX = XB method failed on these poses (the others may still work)."""


def solve_every_method(
    X_WF: Sequence[np.ndarray], X_CT: Sequence[np.ndarray]
) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """X_FC of every OpenCV method, and the reason of each that failed."""
    estimates, failures = {}, {}
    for name in HAND_EYE_METHODS:
        try:
            estimates[name] = solve_hand_eye(X_WF, X_CT, name)
        except HandEyeMethodError as e:
            failures[name] = str(e)
    return estimates, failures


@dataclass(frozen=True)
class MotionSummary:
    """How well the poses excite hand-eye: the largest relative rotation and the largest angle
    between the rotation axes of the motions that rotate at least min_motion_rotation_rad."""

    max_rotation_rad: float
    axis_spread_rad: float
    motions: int


def motion_summary(X_WF: Sequence[np.ndarray], min_motion_rotation_rad: float) -> MotionSummary:
    axes, max_angle = [], 0.0
    for i in range(len(X_WF)):
        for j in range(i + 1, len(X_WF)):
            R_ij = X_WF[i][:3, :3].T @ X_WF[j][:3, :3]
            angle = rotation_angle_rad(R_ij)
            max_angle = max(max_angle, angle)
            if angle >= min_motion_rotation_rad:
                # The motion's axis expressed in W, so different poses' axes are comparable.
                axis = X_WF[i][:3, :3] @ matrix_to_rotvec(R_ij)
                axes.append(axis / np.linalg.norm(axis))
    spread = 0.0
    if len(axes) >= 2:
        A = np.array(axes)
        cos = np.clip(np.abs(A @ A.T), 0.0, 1.0)
        spread = float(np.arccos(cos.min()))
    return MotionSummary(max_angle, spread, len(axes))


def check_motions(X_WF: Sequence[np.ndarray], settings: CalibrationSettings) -> MotionSummary:
    """Refuse pose sets that cannot determine X_FC, saying why (ScannerError)."""
    summary = motion_summary(X_WF, settings.min_motion_rotation_rad)
    if summary.motions == 0:
        raise ScannerError(
            f"degenerate motions: the flange orientations differ by at most "
            f"{math.degrees(summary.max_rotation_rad):.2f} deg; hand-eye calibration needs "
            f"rotations of at least {math.degrees(settings.min_motion_rotation_rad):.1f} deg "
            "between poses (pure translations leave the camera's rotation offset unobservable)"
        )
    if summary.axis_spread_rad < settings.min_axis_spread_rad:
        raise ScannerError(
            f"degenerate motions: all rotations between poses are about one axis (their axes "
            f"differ by at most {math.degrees(summary.axis_spread_rad):.1f} deg, need "
            f"{math.degrees(settings.min_axis_spread_rad):.0f} deg); the hand-eye translation "
            "along that axis is then unobservable: add poses that tilt about another axis"
        )
    return summary

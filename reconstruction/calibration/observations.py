"""One robot pose with the board points its cameras found, and the board pose by PnP."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.calibration.boards import BoardSpec, Detection
from reconstruction.common.transforms import check_pose, pose_from_rvec_tvec
from reconstruction.stereo.camera_model import PinholeCamera


@dataclass(frozen=True, eq=False)
class PoseObservation:
    """One robot pose: its name (file or capture), the flange pose X_WF the robot reported (None
    for a camera-only calibration, which has no robot), the board points each camera found
    (None: board not found), why the left camera's board was not found (empty when it was,
    or when the reason is unknown), and the joints the robot reported (None when the data
    have only poses; the joint offsets need them)."""

    name: str
    X_WF: np.ndarray | None
    left: Detection | None
    right: Detection | None = None
    not_found: str = ""
    q_rad: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.X_WF is None:
            return
        X = check_pose(self.X_WF, f"{self.name}: X_WF").copy()
        X.setflags(write=False)
        object.__setattr__(self, "X_WF", X)


def board_correspondences(board: BoardSpec, detection: Detection) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's (N, 1, 3) board points and (N, 1, 2) pixels of a detection, float32."""
    p_B = board.object_points()[detection.ids].astype(np.float32).reshape(-1, 1, 3)
    return p_B, detection.pixels.astype(np.float32).reshape(-1, 1, 2)


def board_pose(board: BoardSpec, detection: Detection, camera: PinholeCamera) -> np.ndarray:
    """X_CB by PnP: IPPE for the planar board, then Levenberg-Marquardt on all points."""
    p_B, pixels = board_correspondences(board, detection)
    ok, rvec, tvec = cv2.solvePnP(p_B, pixels, camera.K, camera.distortion, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(p_B, pixels, camera.K, camera.distortion)
    rvec, tvec = cv2.solvePnPRefineLM(p_B, pixels, camera.K, camera.distortion, rvec, tvec)
    return pose_from_rvec_tvec(rvec, tvec)

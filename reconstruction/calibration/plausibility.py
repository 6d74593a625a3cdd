"""Whether a hand-eye calibration is physically plausible, and which robot pose convention the
data fit best when it is not (a wrong convention is the usual cause)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from reconstruction.calibration.eye_in_hand import HandEyeCalibration, board_scatter
from reconstruction.calibration.hand_eye import solve_every_method
from reconstruction.calibration.settings import CalibrationSettings


def implausible_figures(hand_eye: HandEyeCalibration, settings: CalibrationSettings) -> list[str]:
    """The figures beyond the settings' limits, each with its limit (empty: plausible)."""
    problems = []
    if hand_eye.rms_px > settings.max_reprojection_rms_px:
        problems.append(
            f"reprojection RMS {hand_eye.rms_px:.1f} px (limit "
            f"{settings.max_reprojection_rms_px:g} px)"
        )
    if hand_eye.board_scatter_max_m > settings.max_board_scatter_m:
        problems.append(
            f"board-in-base scatter {1e3 * hand_eye.board_scatter_max_m:.1f} mm (limit "
            f"{1e3 * settings.max_board_scatter_m:g} mm)"
        )
    offset = float(np.linalg.norm(hand_eye.X_FC[:3, 3]))
    if offset > settings.max_hand_eye_translation_m:
        problems.append(
            f"camera {1e3 * offset:.0f} mm from the flange (limit "
            f"{1e3 * settings.max_hand_eye_translation_m:g} mm)"
        )
    return problems


def board_scatter_of(X_WF: Sequence[np.ndarray], X_CB: Sequence[np.ndarray]) -> float | None:
    """The smallest board-in-base scatter (largest distance from the mean, m) over OpenCV's
    hand-eye methods; None when none of them fits the motions."""
    estimates, _ = solve_every_method(X_WF, X_CB)
    if not estimates:
        return None
    return min(board_scatter(X_WF, X_FC, X_CB)[1] for X_FC in estimates.values())


def rank_conventions(
    poses: Mapping[str, Sequence[np.ndarray]], X_CB: Sequence[np.ndarray]
) -> list[tuple[str, float]]:
    """(convention name, board scatter in m) of every convention that fits, best first."""
    scores = {name: board_scatter_of(X_WF, X_CB) for name, X_WF in poses.items()}
    return sorted(((n, s) for n, s in scores.items() if s is not None), key=lambda ns: ns[1])

"""Whether a hand-eye calibration is physically plausible, and which robot pose convention the
data fit best when it is not (a wrong convention is the usual cause)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from reconstruction.calibration.eye_in_hand import HandEyeCalibration, board_scatter
from reconstruction.calibration.hand_eye import solve_every_method
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import RefusedResultError
from reconstruction.stereo.camera_model import StereoCamera


def implausible_figures(
    hand_eye: HandEyeCalibration, settings: CalibrationSettings, stereo: StereoCamera | None = None
) -> list[str]:
    """The figures of a computed calibration beyond the settings' limits, each with its limit
    (empty: plausible)."""
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
    return problems + implausible_rig(hand_eye.X_FC, stereo, settings)


def implausible_rig(
    X_FC: np.ndarray, stereo: StereoCamera | None, settings: CalibrationSettings
) -> list[str]:
    """The camera's distance from the flange and the stereo baseline beyond the settings'
    limits (what a calibration file holds whether or not anything was measured)."""
    problems = []
    if stereo is not None and stereo.baseline_m > settings.max_baseline_m:
        problems.append(
            f"stereo baseline {1e3 * stereo.baseline_m:.0f} mm (limit "
            f"{1e3 * settings.max_baseline_m:g} mm)"
        )
    offset = float(np.linalg.norm(np.asarray(X_FC)[:3, 3]))
    if offset > settings.max_hand_eye_translation_m:
        problems.append(
            f"camera {1e3 * offset:.0f} mm from the flange (limit "
            f"{1e3 * settings.max_hand_eye_translation_m:g} mm)"
        )
    return problems


def implausible_calibration(
    calibration: Calibration,  # noqa: F821 (calibration.file imports this module)
    settings: CalibrationSettings | None = None,
) -> list[str]:
    """What a calibration file holds beyond the limits a computed calibration is refused at:
    its rig, and its reprojection RMS when it was measured."""
    settings = settings or CalibrationSettings()
    problems = []
    rms = calibration.quality.get("reprojection_rms_px")
    if isinstance(rms, int | float) and rms > settings.max_reprojection_rms_px:
        problems.append(
            f"reprojection RMS {rms:.1f} px (limit {settings.max_reprojection_rms_px:g} px)"
        )
    return problems + implausible_rig(calibration.X_FC, calibration.stereo, settings)


def require_plausible(
    calibration: Calibration,  # noqa: F821 (calibration.file imports this module)
    where: str,
    causes: str,
) -> None:
    """RefusedResultError (exit 3) naming `where` when `calibration` is implausible; `causes`
    says what likely went wrong."""
    problems = implausible_calibration(calibration)
    if problems:
        raise RefusedResultError(
            f"{where}: calibration refused as physically implausible: {'; '.join(problems)}. "
            f"Likely causes: {causes}"
        )


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

"""A hand-eye calibration's quality from the data alone: held-out prediction of the chosen X_FC
and of each closed-form method, X_FC's uncertainty by the bootstrap beside the covariance, and
whether the methods disagree by more than that uncertainty allows. Pure numeric; the figures
and why they are trusted are in `calibration.held_out`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.held_out import (
    Folds,
    HeldOutError,
    Solution,
    bootstrap_twists,
    held_out_closed_form,
    held_out_refined,
)
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.refine import Refinement
from reconstruction.common.transforms import invert, pose_to_twist
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera

# A method whose X_FC lies further than this many sigmas from the chosen one on some axis
# disagrees beyond what the data support.
DISAGREEMENT_SIGMAS = 3.0


@dataclass(frozen=True, eq=False)
class CalibrationQuality:
    """folds: how views were held out; held_out: the chosen X_FC's prediction of held-out views;
    held_out_methods: each OpenCV method's, refitted per fold; bootstrap_sigma: (6,) standard
    deviations of X_FC (rotation rad about C's axes, translation m along them) over refits on
    resampled views; common_sigma: (6,) what the robot's stated accuracy leaves in X_FC (an
    error the same in every pose, which no resampling of the views can see);
    disagreement: per method, its X_FC's difference from the chosen one in units of the
    combined sigma (largest axis); note: what the disagreement means, empty when none."""

    folds: Folds
    held_out: HeldOutError
    held_out_methods: dict[str, HeldOutError]
    bootstrap_sigma: np.ndarray
    common_sigma: np.ndarray
    bootstrap_samples: int
    disagreement_sigmas: dict[str, float]
    note: str

    @property
    def best_method(self) -> str | None:
        if not self.held_out_methods:
            return None
        return min(self.held_out_methods, key=lambda k: self.held_out_methods[k].rms_px)


def combined_sigma(
    covariance: np.ndarray, bootstrap_sigma: np.ndarray, common_sigma: np.ndarray
) -> np.ndarray:
    """Per axis the larger of the covariance's standard deviation (which holds the robot's
    common error already, `eye_in_hand.hand_eye_covariance`) and the bootstrap's with the
    common error added: the covariance sees the image noise and the robot prior, the bootstrap
    the view-to-view differences the robot's real errors make; neither alone is honest on a
    real arm."""
    cov = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return np.fmax(cov, np.hypot(bootstrap_sigma, common_sigma))


def assess(
    board: BoardSpec,
    inliers: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    refined: Refinement,
    X_CB: Sequence[np.ndarray],
    opencv: dict[str, np.ndarray],
    covariance: np.ndarray,
    unobservable_variance: np.ndarray,
    folds: Folds,
    samples: int,
    flange_pose: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> CalibrationQuality:
    """The quality figures of the final refinement `refined` over its poses `inliers`.
    `unobservable_variance` (6,): what no hand-eye data can determine (the last joint's zero),
    added to the bootstrap's variance as the covariance has it."""
    joints = refined.estimated
    solution = Solution(refined.X_FC, refined.X_WB, refined.robot_params)
    held = held_out_refined(
        board, inliers, cameras, refined.linearization, solution, joints, folds, flange_pose
    )
    methods = held_out_closed_form(board, inliers, cameras, X_CB, folds)
    twists = bootstrap_twists(refined.linearization, solution, joints, samples)
    boot = twists.std(axis=0)
    common = np.sqrt(np.clip(unobservable_variance, 0.0, None))
    sigma = combined_sigma(covariance, boot, common)
    distance = {
        name: float(np.max(np.abs(pose_to_twist(invert(refined.X_FC) @ X)) / sigma))
        for name, X in opencv.items()
    }
    return CalibrationQuality(
        folds, held, methods, boot, common, samples, distance, _note(distance, held, methods)
    )


def _note(distance: dict[str, float], held: HeldOutError, methods: dict[str, HeldOutError]) -> str:
    far = sorted(name for name, d in distance.items() if d > DISAGREEMENT_SIGMAS)
    if not far:
        return ""
    order = sorted(methods, key=lambda k: methods[k].rms_px)
    ranked = ", ".join(f"{name} {methods[name].rms_px:.2f} px" for name in order)
    return (
        f"the closed-form methods {', '.join(far)} disagree with the refined X_FC by up to "
        f"{max(distance[n] for n in far):.1f} sigma, more than the data support: the robot's own "
        f"pose errors pull them apart. Held-out prediction decides: refined {held.rms_px:.2f} px"
        + (f"; {ranked}" if ranked else "")
    )

"""The reported standard deviation of X_FC against the simulator's truth over three seeds.

Three calibrations without rendering (`scanner.calibrate.sigma_check.render_free_observations`:
the default stations, the seeded error model, corner noise as measured on the renders), 1-3 s
each: once with the default error model (encoder offsets), once with the robot's kinematic
errors on as well (link lengths off by 0.5-1 mm per calibration) and the solver told the arm's
accuracy. Honesty is a statistic ("at least 9 runs in 10 within 3 sigma"): it is
scripts/bench_calibration_sigma.py's, over seeds 0-9 (and its --rendered version on rendered
calibrations); here every one of the three runs must lie within 3 sigma (measured: at most 0.4
sigma with encoder offsets, 1.74 with link errors).
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from reconstruction.calibration.eye_in_hand import calibrate_hand_eye, hand_eye_covariance
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.transforms import invert, make_pose, pose_to_twist, rotation_about
from robots.models.camera_tool import nominal_X_FC
from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.sigma_check import error_in_sigmas, render_free_observations, summarise

# The simulated arm's accuracy with link lengths off by 0.5-1 mm: what its user would state.
KINEMATIC_ERROR_M = (0.0005, 0.001)
SEEDS = 3
ARM_ACCURACY = {"robot_translation_sigma_m": 0.0005, "robot_rotation_sigma_rad": math.radians(0.02)}


def _ratios(kinematic_error_m=None, **solver):
    config = CalibrateConfig()
    stereo = config.camera.stereo_camera()
    settings = replace(config.solver, **solver)
    rows = []
    for observations, X_FC_true, _ in render_free_observations(
        config, range(SEEDS), kinematic_error_m
    ):
        he = calibrate_hand_eye(config.board, observations, stereo, settings)
        rows.append((he, error_in_sigmas(he.X_FC, he.X_FC_sigma, X_FC_true)))
    return rows


@pytest.fixture(scope="module")
def encoder_errors():
    return _ratios()


@pytest.fixture(scope="module")
def kinematic_errors():
    return _ratios(KINEMATIC_ERROR_M, **ARM_ACCURACY)


@pytest.mark.slow
def test_the_true_error_lies_within_3_sigma_in_9_of_10_runs(encoder_errors):
    # Nine of ten over seeds 0-9 is bench_calibration_sigma.py's; three of three here.
    summary = summarise([r for _, r in encoder_errors])
    assert summary.runs == SEEDS
    assert summary.within_3sigma == SEEDS, summary
    # Not honest by being huge: the data's part stays a few hundredths of a mm; the rest is
    # the robot's stated accuracy (0.2 mm, 0.02 deg), which no hand-eye data can see through.
    sigma = np.array([he.X_FC_sigma for he, _ in encoder_errors])
    assert np.all(sigma[:, 3:] < 0.3e-3)  # m
    assert np.all(sigma[:, :3] < np.radians(0.05))
    boot = np.array([he.quality.bootstrap_sigma for he, _ in encoder_errors])
    assert np.all(boot[:, 3:] <= sigma[:, 3:])


@pytest.mark.slow
def test_with_the_robots_kinematic_errors_the_sigma_still_holds(kinematic_errors):
    """Link-length errors move X_FC by up to ~1.5 mm, the same in every view of a calibration:
    neither the covariance nor the bootstrap can see them (measured 2-18 sigma off without the
    robot's accuracy term); with the arm's stated accuracy the truth lies within 3 sigma."""
    ratios = [r for _, r in kinematic_errors]
    summary = summarise(ratios)
    assert summary.within_3sigma == SEEDS, summary
    # And not uselessly wide: on average the errors are a sizeable fraction of their sigmas
    # (measured: 0.378 over these three runs, 0.421 over ten).
    assert 0.3 < float(np.mean(ratios)) < 1.5


def test_the_common_robot_error_term_is_the_twist_of_a_constant_flange_error():
    """A flange error E the same in every pose turns X_FC into E X_FC: the added covariance is
    the twist of that change (checked by finite differences, one flange axis at a time) scaled
    by the robot's accuracy."""
    X_FC = nominal_X_FC(0.12) @ make_pose(rotation_about(np.array([1.0, 2.0, 3.0]), 0.3), [0, 0, 0])
    settings = CalibrationSettings()
    added = hand_eye_covariance(np.zeros((6, 6)), X_FC, settings)
    d = 1e-6
    expected = np.zeros((6, 6))
    for axis in range(3):
        unit = np.eye(3)[axis]
        roll = make_pose(rotation_about(unit, d), [0, 0, 0])
        shift = make_pose(np.eye(3), d * unit)
        for E, sigma in (
            (roll, settings.robot_rotation_sigma_rad),
            (shift, settings.robot_translation_sigma_m),
        ):
            g = pose_to_twist(invert(X_FC) @ E @ X_FC) / d
            expected += sigma**2 * np.outer(g, g)
    assert np.allclose(added, expected, rtol=1e-4, atol=1e-6 * np.abs(expected).max())
    trusted = CalibrationSettings(robot_translation_sigma_m=0.0, robot_rotation_sigma_rad=0.0)
    assert np.all(hand_eye_covariance(np.eye(6), X_FC, trusted) == np.eye(6))

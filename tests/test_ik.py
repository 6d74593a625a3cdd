"""Closed-form IK of the RX60 against Drake's forward kinematics, and look-at camera poses."""

import math

import numpy as np
import pytest

from planners.ik import Viewpoint, camera_pose, ik_camera, rig_centre_offset
from reconstruction.stereo.camera_model import default_stereo_camera
from robots.arms.rx60 import RX60, ik_flange, rx60_arm
from robots.models.camera_tool import nominal_X_FC
from robots.models.kinematics import Kinematics

# Issue 3: position error <= 0.1 mm, orientation error <= 0.05 deg.
POSITION_TOL_M = 1e-4
ROTATION_TOL_RAD = math.radians(0.05)


def pose_errors(X_a: np.ndarray, X_b: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation angle rad) between two poses."""
    dp = float(np.linalg.norm(X_a[:3, 3] - X_b[:3, 3]))
    cos = (np.trace(X_a[:3, :3].T @ X_b[:3, :3]) - 1) / 2
    return dp, math.acos(min(1.0, max(-1.0, cos)))


@pytest.fixture(scope="module")
def kinematics():
    return Kinematics(rx60_arm())


def test_round_trip_on_random_reachable_poses(kinematics):
    robot = RX60()
    X_FC = nominal_X_FC()
    rng = np.random.default_rng(7)
    found_own_q = 0
    for _ in range(200):
        q = rng.uniform(robot.lower, robot.upper)
        X_WC = kinematics.X_WC(q, X_FC)
        solutions = ik_camera(rx60_arm(robot), X_WC, X_FC, q)
        assert solutions, "a pose produced by FK must be reachable"
        for q_ik in solutions:
            assert robot.within_limits(q_ik)
            dp, dr = pose_errors(kinematics.X_WC(q_ik, X_FC), X_WC)
            assert dp < POSITION_TOL_M
            assert dr < ROTATION_TOL_RAD
        # Away from the wrist singularity the branches are distinct, so q itself is one of them.
        if abs(math.sin(q[4])) > 1e-3:
            assert min(np.abs(q_ik - q).max() for q_ik in solutions) < 1e-6
            found_own_q += 1
    assert found_own_q > 150


def test_all_branches_are_found():
    """A generic pose away from limits has shoulder x elbow x wrist = 8 branches (more with the
    +-2 pi copies of J4/J6 that the +-270 deg ranges allow)."""
    robot = RX60()
    q = np.array([0.3, 0.2, 0.9, 0.4, 0.7, -0.3])
    X_WF = Kinematics(rx60_arm(robot)).X_WF(q)
    solutions = ik_flange(robot, X_WF, q)
    distinct_q5_q3 = {(round(s[1], 6), round(s[2], 6), round(s[4], 6)) for s in solutions}
    assert len(distinct_q5_q3) >= 4
    assert len(solutions) >= 8


def test_unreachable_pose_has_no_solution():
    X_WF = np.eye(4)
    X_WF[:3, 3] = (2.0, 0.0, 0.5)  # beyond the ~0.7 m reach
    assert ik_flange(RX60(), X_WF) == []


def test_look_at_solutions_aim_the_rig_centre_at_the_target(kinematics):
    robot = RX60()
    stereo = default_stereo_camera()
    X_FC = nominal_X_FC(stereo.baseline_m)
    X_MC = rig_centre_offset(stereo.X_CR)
    target = np.array([0.30, 0.0, 0.78])
    checked = 0
    for azimuth_deg in range(100, 261, 20):
        for elevation_deg in (-50, -30, -10):
            az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
            d = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
            vp = Viewpoint(tuple(target + 0.5 * d), tuple(target), 0.2)
            X_WC_wanted = camera_pose(vp, X_MC)
            for q in ik_camera(rx60_arm(robot), X_WC_wanted, X_FC):
                X_WC = kinematics.X_WC(q, X_FC)
                dp, dr = pose_errors(X_WC, X_WC_wanted)
                assert dp < POSITION_TOL_M and dr < ROTATION_TOL_RAD
                X_WM = X_WC @ np.linalg.inv(X_MC)
                to_target = target - X_WM[:3, 3]
                assert np.linalg.norm(to_target) == pytest.approx(0.5, abs=1e-6)
                # The rig's optical axis passes through the target.
                miss = np.linalg.norm(np.cross(X_WM[:3, 2], to_target))
                assert miss < POSITION_TOL_M
                checked += 1
    assert checked > 20

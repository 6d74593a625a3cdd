"""The RX60 model against the datasheet: FK by an independent product of exponentials, limits."""

import math

import numpy as np
import pytest

from robots.arms.rx60 import RX60, rx60_arm
from robots.models.camera_tool import nominal_X_FC, tool_collision_box, tool_visual_boxes
from robots.models.kinematics import Kinematics
from robots.models.workcell import WorkcellConfig, build_workcell

DEG = math.pi / 180


def _twist_exp(w, q, theta):
    """exp([xi] theta) for a revolute joint with unit axis w through point q (Rodrigues)."""
    w = np.asarray(w, float)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    R = np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * K @ K
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = (np.eye(3) - R) @ np.asarray(q, float)
    return X


def poe_flange(q):
    """Space-frame product of exponentials written from the datasheet numbers only."""
    h, a2, d, a3, l6 = 0.341, 0.290, 0.049, 0.310, 0.065
    axes = [
        ((0, 0, 1), (0, 0, 0)),
        ((0, 1, 0), (0, 0, h)),
        ((0, 1, 0), (0, d, h + a2)),
        ((0, 0, 1), (0, d, 0)),
        ((0, 1, 0), (0, d, h + a2 + a3)),
        ((0, 0, 1), (0, d, 0)),
    ]
    M = np.eye(4)
    M[:3, 3] = (0, d, h + a2 + a3 + l6)
    X = np.eye(4)
    for (w, p), theta in zip(axes, q):
        X = X @ _twist_exp(w, p, theta)
    return X @ M


def test_fk_matches_product_of_exponentials():
    robot = RX60()
    kin = Kinematics(rx60_arm(robot))
    rng = np.random.default_rng(7)
    for _ in range(100):
        q = rng.uniform(robot.lower, robot.upper)
        X_drake = kin.X_WF(q)
        X_poe = poe_flange(q)
        assert np.linalg.norm(X_drake[:3, 3] - X_poe[:3, 3]) < 1e-9
        assert np.abs(X_drake[:3, :3] - X_poe[:3, :3]).max() < 1e-9


def test_joint_limits_and_speeds_as_documented():
    robot = RX60()
    cell = build_workcell(WorkcellConfig(), None, nominal_X_FC(), np.eye(4), rx60_arm(robot))
    plant = cell.plant
    lo_deg = [-160, -127.5, -134.5, -270, -109.5, -270]
    hi_deg = [160, 127.5, 134.5, 270, 120.5, 270]
    speed_deg = [287, 287, 319, 410, 320, 700]
    np.testing.assert_allclose(plant.GetPositionLowerLimits(), np.radians(lo_deg), atol=1e-12)
    np.testing.assert_allclose(plant.GetPositionUpperLimits(), np.radians(hi_deg), atol=1e-12)
    np.testing.assert_allclose(plant.GetVelocityUpperLimits(), np.radians(speed_deg), atol=1e-12)
    assert all(a > 0 for a in robot.acceleration_limits_rad_s2)


def test_tool_collision_box_has_10mm_margin():
    c = tool_collision_box()
    c_lo = np.subtract(c.p_FB, np.divide(c.size, 2))
    c_hi = np.add(c.p_FB, np.divide(c.size, 2))
    for b in tool_visual_boxes():
        lo = np.subtract(b.p_FB, np.divide(b.size, 2))
        hi = np.add(b.p_FB, np.divide(b.size, 2))
        assert np.all(lo - c_lo >= 0.010 - 1e-12)
        assert np.all(c_hi - hi >= 0.010 - 1e-12)


def test_camera_frames_follow_the_hand_eye_transform():
    robot = RX60()
    X_FC = nominal_X_FC()
    X_CR = np.eye(4)
    X_CR[0, 3] = 0.12
    cell = build_workcell(WorkcellConfig(), None, X_FC, X_CR, rx60_arm(robot))
    plant = cell.plant
    context = plant.CreateDefaultContext()
    q = np.array([0.3, -0.2, 1.2, 0.4, -0.5, 0.6])
    plant.SetPositions(context, cell.robot, q)
    X_WC = plant.GetFrameByName("camera_left").CalcPoseInWorld(context).GetAsMatrix4()
    X_WR = plant.GetFrameByName("camera_right").CalcPoseInWorld(context).GetAsMatrix4()
    np.testing.assert_allclose(X_WC, Kinematics(rx60_arm(robot)).X_WC(q, X_FC), atol=1e-12)
    assert np.linalg.norm(X_WR[:3, 3] - X_WC[:3, 3]) == pytest.approx(0.12, abs=1e-12)

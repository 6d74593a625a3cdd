"""Arms from files: FK against independent kinematics, IK round trips, determinism, the 7-axis
grid, the one-line errors of bad arm files, and an arm added by writing two files."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix

from reconstruction.common.errors import ScannerError
from robots.arms.arm import load_arm, load_arm_file
from robots.arms.arm_file import read_arm_file
from robots.arms.general_ik import redundant_grid
from robots.arms.model import load_arm_plant, model_text
from tests.tiny_arm import write_tiny_arm

ARMS = Path(__file__).resolve().parents[1] / "scanner" / "configs" / "arms"
# Double-precision kinematics: FK of two implementations agree to rounding.
FK_TRANSLATION_TOL_M = 1e-9
FK_ROTATION_TOL_RAD = 1e-9
# What an IK solution must reach (the settings ask 1e-9; 1e-6 is the brief's bound).
IK_TRANSLATION_TOL_M = 1e-6
IK_ROTATION_TOL_RAD = 1e-6


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _axis_angle(axis, a):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def _pose(R, p):
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, p
    return X


def urdf_chain_pose(urdf: str, flange: str, q: dict[str, float]) -> np.ndarray:
    """X_RF (4x4) of link `flange` in the URDF's root link, composed by hand from the joints'
    origins (rpy = Rz(y) Ry(p) Rx(r), URDF convention) and axes."""
    joints = {j.find("child").get("link"): j for j in ET.fromstring(urdf).findall("joint")}
    X, link = np.eye(4), flange
    while link in joints:
        joint = joints[link]
        origin = joint.find("origin")
        xyz = [
            float(v)
            for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()
        ]
        rpy = [
            float(v)
            for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()
        ]
        X_PJ = _pose(_rot_z(rpy[2]) @ _rot_y(rpy[1]) @ _rot_x(rpy[0]), xyz)
        if joint.get("type") in ("revolute", "continuous"):
            axis = [float(v) for v in joint.find("axis").get("xyz").split()]
            X_PJ = X_PJ @ _pose(_axis_angle(axis, q[joint.get("name")]), np.zeros(3))
        X = X_PJ @ X
        link = joint.find("parent").get("link")
    return X


def assert_pose_close(X_a: np.ndarray, X_b: np.ndarray, rot_tol: float, trans_tol: float):
    R_err = RotationMatrix(X_a[:3, :3] @ X_b[:3, :3].T)
    angle = abs(R_err.ToAngleAxis().angle())
    assert angle < rot_tol
    assert np.linalg.norm(X_a[:3, 3] - X_b[:3, 3]) < trans_tol


@pytest.fixture(scope="session")
def ur5e():
    return load_arm(ARMS / "ur5e.yaml")


@pytest.fixture(scope="session")
def iiwa14():
    return load_arm(ARMS / "iiwa14.yaml")


def _random_q(arm, rng):
    return rng.uniform(np.maximum(arm.lower, -math.pi), np.minimum(arm.upper, math.pi))


# --- forward kinematics ------------------------------------------------------------------------


def ur5e_dh_tool0(q: np.ndarray) -> np.ndarray:
    """X_B6 of the UR5e from UR's published DH table (base 'B' = ROS 'base', frame 6 = tool0)."""
    d = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
    a = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
    alpha = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
    X = np.eye(4)
    for qi, di, ai, al in zip(q, d, a, alpha):
        X = X @ _pose(_rot_z(qi), [0, 0, di]) @ _pose(_rot_x(al), [ai, 0, 0])
    return X


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ur5e_fk_matches_ur_dh_table(ur5e, seed):
    # ROS 'base' is base_link turned half a turn about z (ur_macro.xacro), X_WB = identity here.
    q = _random_q(ur5e, np.random.default_rng(seed))
    X_W_base = _pose(_rot_z(math.pi), np.zeros(3))
    expected = X_W_base @ ur5e_dh_tool0(q)
    # The xacro writes pi/2 as 1.570796327 and carries 2e-11 m offsets the DH table rounds off.
    assert_pose_close(ur5e.X_WF(q).GetAsMatrix4(), expected, 1e-8, 1e-8)


def test_ur5e_zero_pose_flange(ur5e):
    # UR5e DH: reach a2 + a3 = 0.8172 m, offsets d4 + d6 = 0.2329 m, height d1 - d5 = 0.0628 m.
    p = ur5e.X_WF(np.zeros(6)).translation()
    np.testing.assert_allclose(p, [0.8172, 0.2329, 0.0628], atol=1e-9)


def test_iiwa14_zero_pose_flange_height(iiwa14):
    # KUKA LBR iiwa 14 R820 datasheet: 360 + 420 + 400 + 126 mm from base to flange, upright.
    X_WF = iiwa14.X_WF(np.zeros(7))
    np.testing.assert_allclose(X_WF.translation(), [0, 0, 1.306], atol=1e-9)


@pytest.mark.parametrize("name", ["ur5e", "iiwa14"])
def test_fk_matches_hand_composed_urdf_chain(name, ur5e, iiwa14):
    arm = {"ur5e": ur5e, "iiwa14": iiwa14}[name]
    arm_file = read_arm_file(ARMS / f"{name}.yaml")
    urdf, _ = model_text(arm_file)
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = _random_q(arm, rng)
        expected = urdf_chain_pose(urdf, arm.flange_frame, dict(zip(arm.joint_names, q)))
        assert_pose_close(
            arm.X_WF(q).GetAsMatrix4(), expected, FK_ROTATION_TOL_RAD, FK_TRANSLATION_TOL_M
        )


# --- inverse kinematics ------------------------------------------------------------------------


def _assert_solutions_reach(arm, solutions, X_WF_target):
    for q in solutions:
        assert_pose_close(
            arm.X_WF(q).GetAsMatrix4(),
            X_WF_target.GetAsMatrix4(),
            IK_ROTATION_TOL_RAD,
            IK_TRANSLATION_TOL_M,
        )
        assert np.all(q >= arm.lower) and np.all(q <= arm.upper)


def _contains(solutions, q):
    return len(solutions) > 0 and np.min(np.max(np.abs(solutions - q), axis=1)) < 1e-6


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_ur5e_ik_round_trip(ur5e, seed):
    q = _random_q(ur5e, np.random.default_rng(seed))
    X_WF = ur5e.X_WF(q)
    solutions = ur5e.ik(X_WF)
    _assert_solutions_reach(ur5e, solutions, X_WF)
    assert _contains(solutions, q)
    # Five joints range over two turns: every branch comes with its whole-turn copies.
    assert len(solutions) % 32 == 0


def test_ik_is_deterministic(ur5e):
    X_WF = ur5e.X_WF(_random_q(ur5e, np.random.default_rng(20)))
    first, second = ur5e.ik(X_WF), ur5e.ik(X_WF)
    assert first.shape == second.shape and np.array_equal(first, second)


def test_iiwa14_ik_on_the_redundant_grid(iiwa14):
    arm_file = read_arm_file(ARMS / "iiwa14.yaml")
    grid = redundant_grid(load_arm_plant(arm_file), arm_file.ik)
    assert len(grid) == 9 and grid[0] == iiwa14.lower[2] and grid[-1] == iiwa14.upper[2]
    q = _random_q(iiwa14, np.random.default_rng(30))
    q[2] = grid[3]
    X_WF = iiwa14.X_WF(q)
    solutions = iiwa14.ik(X_WF)
    _assert_solutions_reach(iiwa14, solutions, X_WF)
    assert _contains(solutions, q)
    assert all(np.any(np.abs(grid - v) < 1e-12) for v in solutions[:, 2])
    assert np.array_equal(solutions, iiwa14.ik(X_WF))


def test_unreachable_pose_has_no_solution(ur5e):
    X_WF = RigidTransform(np.array([3.0, 0.0, 0.0]))
    assert ur5e.ik(X_WF).shape == (0, 6)


# --- adding an arm is a file ---------------------------------------------------------------------


def test_an_arm_added_as_files_loads_and_solves(tmp_path):
    arm = load_arm(write_tiny_arm(tmp_path))
    assert arm.joint_names == tuple(f"j{i}" for i in range(1, 7))
    np.testing.assert_allclose(arm.acceleration, 5.0)
    # Upright at q = 0: the base pose's offset, then the column, arms and flange stacked.
    np.testing.assert_allclose(arm.X_WF(np.zeros(6)).translation(), [0.1, 0.2, 1.13], atol=1e-12)
    q = np.array([0.3, 0.5, 0.9, -0.4, 0.7, 1.1])
    X_WF = arm.X_WF(q)
    solutions = arm.ik(X_WF)
    _assert_solutions_reach(arm, solutions, X_WF)
    assert _contains(solutions, q)


# --- bad arm files: one line naming the file and the field ---------------------------------------


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"model": "missing.urdf"}, "model"),
        ({"accuracy_m": None}, "accuracy_m"),
        ({"flange_link": "link9"}, "flange_link"),
        ({"joint_limits": None}, "joint_limits.j1.acceleration_rad_s2"),
        ({"packages": "{meshes: no_such_folder}"}, "packages.meshes"),
        ({"base_pose": "{xyz_m: [0, 0], rpy_rad: [0, 0, 0]}"}, "base_pose.xyz_m"),
        ({"colour": "orange"}, "colour"),
    ],
)
def test_bad_arm_file_gives_one_line_naming_the_field(tmp_path, overrides, field):
    path = write_tiny_arm(tmp_path, **overrides)
    with pytest.raises(ScannerError) as error:
        load_arm_file(path)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {field}")


def test_arm_file_that_does_not_parse(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: [unclosed\n")
    with pytest.raises(ScannerError) as error:
        load_arm_file(path)
    assert "\n" not in str(error.value) and str(path) in str(error.value)

"""Planning asks the arm, not a model: the UR5e from its arm file is planned in the work cell by
the planner the RX60 uses (roadmap, timing, dense validation), and planners/ names no arm."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from planners.collision import CollisionChecker
from planners.config import PlannerConfig
from planners.planner import Planner, Trajectory
from reconstruction.stereo.camera_model import default_stereo_camera
from robots.arms.arm import load_arm
from robots.arms.default import DEFAULT_ARM
from robots.models.camera_tool import nominal_X_FC
from robots.models.kinematics import Kinematics
from robots.models.workcell import WorkcellConfig, build_workcell

ROOT = Path(__file__).resolve().parents[1]
ARMS = ROOT / "scanner" / "configs" / "arms"
# The validation's own bound: no joint moves more than 0.25 deg between checked samples.
MAX_STEP_RAD = math.radians(0.25)
# Finite differences at sub-millisecond steps approximate the true derivatives to well within
# these relative margins (as for the RX60 in test_planning).
VELOCITY_SLACK = 1.01
ACCELERATION_SLACK = 1.05
# IK solutions reach their pose to rounding; the planner's ends are those solutions exactly.
POSE_TRANSLATION_TOL_M = 1e-6
POSE_ROTATION_TOL_RAD = 1e-6
# A roadmap this size builds in well under a second for the UR5e and has routes around the
# blocked straight move below.
ROADMAP = dict(roadmap_milestones=400, prm_build_time_s=20.0, query_time_s=1.0)
# Elbow up, wrist down: the UR5e's usual ready pose, from which the nearest solution is taken.
READY_Q = np.array([0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0])
# Two reachable flange poses, the flange facing the table: one left, above the table; one right
# and low in front. Reached elbow up and elbow down, the straight joint move between them is
# blocked.
X_WF_A = RigidTransform(RollPitchYaw(math.pi, 0.0, 0.0), np.array([0.30, 0.35, 0.40]))
X_WF_B = RigidTransform(RollPitchYaw(math.pi, 0.0, 0.0), np.array([0.35, -0.30, 0.15]))


def rig():
    stereo = default_stereo_camera()
    return nominal_X_FC(stereo.baseline_m), stereo.X_CR


@pytest.fixture(scope="module")
def ur5e():
    return load_arm(ARMS / "ur5e.yaml")


@pytest.fixture(scope="module")
def planner(ur5e):
    X_FC, X_CR = rig()
    cell = build_workcell(WorkcellConfig(), None, X_FC, X_CR, ur5e)
    return Planner(cell, X_FC, X_CR, PlannerConfig(**ROADMAP), ur5e)


def free_solution(planner: Planner, X_WF: RigidTransform, elbow_sign: float) -> np.ndarray:
    """The collision-free IK solution with the elbow on the given side nearest READY_Q."""
    solutions = planner.arm.ik(X_WF)
    assert len(solutions) > 0, "the pose is reachable"
    free = [q for q in solutions if np.sign(q[2]) == elbow_sign and planner.is_collision_free(q)]
    assert free, "some solution is collision-free"
    return min(free, key=lambda q: float(np.abs(q - READY_Q).max()))


def assert_pose_close(X_a: RigidTransform, X_b: RigidTransform) -> None:
    angle = RotationMatrix(X_a.rotation().matrix() @ X_b.rotation().matrix().T).ToAngleAxis()
    assert abs(angle.angle()) < POSE_ROTATION_TOL_RAD
    assert np.linalg.norm(X_a.translation() - X_b.translation()) < POSE_TRANSLATION_TOL_M


@pytest.mark.parametrize("which", ["default", "ur5e"])
def test_closed_form_and_file_arms_answer_one_interface(which, ur5e):
    arm = {"default": DEFAULT_ARM, "ur5e": ur5e}[which]
    assert arm.joint_count == len(arm.joint_names) == 6
    for limits in (arm.lower, arm.upper, arm.velocity, arm.acceleration):
        assert limits.shape == (6,) and not limits.flags.writeable
    assert np.all(arm.lower < arm.upper) and np.all(arm.velocity > 0)
    assert np.all(arm.acceleration > 0)
    # The arm's own FK (closed form or its plant) against the model it adds to a plant.
    kinematics = Kinematics(arm)
    q = np.array([0.3, -1.2, 1.1, -0.4, 0.7, 0.2])
    X_WF = arm.X_WF(q)
    assert_pose_close(X_WF, RigidTransform(kinematics.X_WF(q)))
    solutions = arm.ik(X_WF, q)
    assert solutions.shape[1] == 6
    assert np.min(np.abs(solutions - q).max(axis=1)) < 1e-6
    for q_ik in solutions:
        assert arm.within_limits(q_ik)
        assert_pose_close(arm.X_WF(q_ik), X_WF)


def test_ur5e_arm_builds_the_cell_the_planner_checks(ur5e, planner):
    assert planner.workcell.plant.num_positions() == ur5e.joint_count == 6
    assert planner.space.joints == 6 and planner.roadmap.vertices_rad.shape[1] == 6
    assert planner.is_collision_free(READY_Q)
    # The camera frames ride on the UR5e's flange.
    plant = planner.workcell.plant
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, READY_Q)
    X_WC = plant.GetFrameByName("camera_left").CalcPoseInWorld(context)
    X_FC, _ = rig()
    assert_pose_close(X_WC, ur5e.X_WF(READY_Q) @ RigidTransform(X_FC))


def test_ur5e_prm_path_between_ik_solutions_is_timed_and_validated(ur5e, planner):
    q_a = free_solution(planner, X_WF_A, elbow_sign=1.0)
    q_b = free_solution(planner, X_WF_B, elbow_sign=-1.0)
    assert_pose_close(ur5e.X_WF(q_a), X_WF_A)
    assert_pose_close(ur5e.X_WF(q_b), X_WF_B)
    assert not planner.checker.edge_free(q_a, q_b), "the straight move is blocked"

    result = planner.plan(q_a, q_b)
    assert isinstance(result, Trajectory), result
    assert result.stats.method == "roadmap"
    assert len(result.path_rad) > 2
    assert planner.validate(result, q_a, q_b).ok

    # Independent recheck: uniform time samples at <= 0.25 deg steps at the fastest joint, the
    # UR5e's limits by finite differences, collisions by a separately built cell.
    assert np.array_equal(result.sample(0.0), q_a)
    assert np.array_equal(result.sample(result.duration_s), q_b)
    v, a = ur5e.velocity, ur5e.acceleration
    n = max(3, math.ceil(result.duration_s / (MAX_STEP_RAD / v.max())) + 1)
    t = np.linspace(0.0, result.duration_s, n)
    q = result.samples(t)
    assert np.abs(np.diff(q, axis=0)).max() <= MAX_STEP_RAD
    assert np.all(q >= ur5e.lower) and np.all(q <= ur5e.upper)
    h = t[1] - t[0]
    assert np.all(np.abs(np.diff(q, axis=0) / h) <= VELOCITY_SLACK * v)
    assert np.all(np.abs(np.diff(q, 2, axis=0) / h**2) <= ACCELERATION_SLACK * a)
    X_FC, X_CR = rig()
    cell = build_workcell(WorkcellConfig(), None, X_FC, X_CR, ur5e)
    checker = CollisionChecker(cell, planner.config.padding_m, planner.config.edge_step_rad)
    assert checker.are_free(q).all()


def test_planners_name_no_arm_model():
    # Planning asks robots.arms.Arm; the RX60 (or any arm) is named where arms are made.
    for path in sorted((ROOT / "planners").glob("*.py")) + [
        ROOT / "robots" / "models" / "workcell.py"
    ]:
        text = path.read_text()
        assert not re.search(r"rx60", text, re.IGNORECASE), f"{path.name} names the RX60"


# The controller of the Staubli arms (its driver and emulator) is the RX60's by nature; the
# calibration's sigma benchmark simulates link-length errors on the RX60's closed form alone.
ARM_SPECIFIC = {
    "robots/drivers/staubli_val3.py",
    "robots/emulator/val3_server.py",
    "scanner/calibrate/sigma_check.py",
}


def test_only_the_arm_package_imports_an_arm_model():
    # Everything else asks robots.arms (the Arm, the default arm, an arm file) for its arm; the
    # arms other than the RX60 are files (scanner/configs/arms), not modules.
    pattern = re.compile(r"^\s*(from|import)\s+robots\.arms\.rx60\b")
    found = []
    for folder in ("scanner", "robots", "planners", "reconstruction"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            name = path.relative_to(ROOT).as_posix()
            if name.startswith("robots/arms/") or name in ARM_SPECIFIC:
                continue
            lines = path.read_text().splitlines()
            found += [f"{name}:{k + 1}" for k, line in enumerate(lines) if pattern.match(line)]
    assert not found, found


def test_no_arm_model_file_is_named_outside_the_arm_package():
    # An arm's model (URDF, SDF, xacro) is named by the arm package or by an arm file only; the
    # rest of the product, the VAL 3 driver included, gets its model through the Arm.
    pattern = re.compile(r"[\w./-]+\.(urdf|sdf|xacro)\b", re.IGNORECASE)
    found = []
    for folder in ("scanner", "robots", "planners", "reconstruction"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            name = path.relative_to(ROOT).as_posix()
            if name.startswith("robots/arms/"):
                continue
            for k, line in enumerate(path.read_text().splitlines()):
                found += [f"{name}:{k + 1}: {m.group(0)}" for m in pattern.finditer(line)]
    assert not found, found

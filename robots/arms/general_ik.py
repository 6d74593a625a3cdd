"""Inverse kinematics of any serial arm, numerically, with answers that do not depend on chance.

Drake's InverseKinematics (flange position and orientation, joint limits) is solved with SNOPT
from a fixed set of seeds (a scrambled Halton sequence with a fixed seed over the joint ranges),
each answer polished by Gauss-Newton steps to machine precision and kept only if it reaches the
target within tolerance and the limits. Answers reached from several seeds are one solution;
then, as for the RX60's closed form, every joint whose range exceeds 2 pi adds its copies shifted
by whole turns that stay within the limits. Rows are sorted, so the same request gives the same
array.

An arm with more than 6 joints has a continuum of solutions: its redundant joint (by default the
third, the elbow's swivel on an iiwa-like arm) is fixed in turn at each value of an even grid over
its range, and the other joints solved for each value.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.solvers import SnoptSolver
from scipy.stats import qmc

from robots.arms.arm_file import IkSettings

DEFAULT_IK_SETTINGS = IkSettings()

if TYPE_CHECKING:
    from robots.arms.model import ArmPlant

TWO_PI = 2 * math.pi
# SNOPT stops near its feasibility tolerance (about 1e-6); the polish does the rest. The
# orientation bound is not 0 because Drake's constraint on the angle has no gradient at 0.
SOLVER_POSITION_TOLERANCE_M = 1e-6
SOLVER_ORIENTATION_TOLERANCE_RAD = 1e-4
POLISH_STEPS = 20
# Halton with this seed: the fixed seeds of every request.
SEED_SEQUENCE_SEED = 0


def redundant_index(arm: ArmPlant, settings: IkSettings) -> int | None:
    """Index of the joint fixed on a grid, or None for an arm of at most 6 joints."""
    if len(arm.joint_names) <= 6:
        return None
    if settings.redundant_joint is None:
        return 2
    return arm.joint_names.index(settings.redundant_joint)


def redundant_grid(arm: ArmPlant, settings: IkSettings) -> np.ndarray:
    """The values the redundant joint takes (empty for an arm of at most 6 joints)."""
    r = redundant_index(arm, settings)
    if r is None:
        return np.zeros(0)
    return np.linspace(arm.lower[r], arm.upper[r], settings.redundant_steps)


def seed_positions(arm: ArmPlant, count: int) -> np.ndarray:
    """(count, n) fixed starting positions, spread over the limits clipped to one turn."""
    lower = np.where(arm.revolute, np.maximum(arm.lower, -math.pi), arm.lower)
    upper = np.where(arm.revolute, np.minimum(arm.upper, math.pi), arm.upper)
    unit = qmc.Halton(d=len(lower), scramble=True, seed=SEED_SEQUENCE_SEED).random(count)
    return lower + unit * (upper - lower)


def _pose_error(arm: ArmPlant, context, X_WF_target: RigidTransform) -> np.ndarray:
    """[rotation vector of R_target R^T; p_target - p] in the world, like a spatial velocity."""
    X_WF = arm.flange_frame.CalcPoseInWorld(context)
    R_err = RotationMatrix(X_WF_target.rotation().matrix() @ X_WF.rotation().matrix().T)
    angle_axis = R_err.ToAngleAxis()
    return np.concatenate(
        [angle_axis.angle() * angle_axis.axis(), X_WF_target.translation() - X_WF.translation()]
    )


def _polish(arm: ArmPlant, q: np.ndarray, X_WF_target: RigidTransform, free: np.ndarray):
    """Gauss-Newton on the free joints from `q`; (q, final pose error)."""
    plant, world = arm.plant, arm.plant.world_frame()
    context = plant.CreateDefaultContext()
    q = q.copy()
    for _ in range(POLISH_STEPS):
        plant.SetPositions(context, arm.plant_positions(q))
        error = _pose_error(arm, context, X_WF_target)
        if np.max(np.abs(error)) < 1e-14:
            break
        J = plant.CalcJacobianSpatialVelocity(
            context, JacobianWrtVariable.kQDot, arm.flange_frame, np.zeros(3), world, world
        )[:, arm.position_starts]
        q[free] += np.linalg.lstsq(J[:, free], error, rcond=None)[0]
    plant.SetPositions(context, arm.plant_positions(q))
    return q, _pose_error(arm, context, X_WF_target)


def _wide(arm: ArmPlant) -> np.ndarray:
    return arm.revolute & (arm.upper - arm.lower > TWO_PI)


def _same(a: np.ndarray, b: np.ndarray, wide: np.ndarray, tolerance: float) -> bool:
    d = a - b
    d[wide] = (d[wide] + math.pi) % TWO_PI - math.pi
    return bool(np.max(np.abs(d)) <= tolerance)


def _turn_variants(arm: ArmPlant, q: np.ndarray) -> list[np.ndarray]:
    """`q` and its copies with wide joints shifted by whole turns, within the limits."""
    variants = [q]
    for i in np.flatnonzero(_wide(arm)):
        shifts = range(
            math.ceil((arm.lower[i] - q[i]) / TWO_PI - 1e-12),
            math.floor((arm.upper[i] - q[i]) / TWO_PI + 1e-12) + 1,
        )
        variants = [v + k * TWO_PI * np.eye(len(q))[i] for v in variants for k in shifts]
    return variants


def _within_limits(arm: ArmPlant, q: np.ndarray) -> np.ndarray | None:
    """`q` clipped to the limits if it is at most a rounding error outside, else None."""
    if np.any(q < arm.lower - 1e-9) or np.any(q > arm.upper + 1e-9):
        return None
    return np.clip(q, arm.lower, arm.upper)


def solve_ik(
    arm: ArmPlant, X_WF_target: RigidTransform, settings: IkSettings = DEFAULT_IK_SETTINGS
) -> np.ndarray:
    """All distinct joint vectors (k, n) that put the flange at X_WF_target, sorted; (0, n) when
    none was found. On a redundant arm, only those with the redundant joint on its grid."""
    n = len(arm.joint_names)
    r = redundant_index(arm, settings)
    fixed_values = [None] if r is None else list(redundant_grid(arm, settings))
    free = np.ones(n, bool)
    if r is not None:
        free[r] = False
    seeds = seed_positions(arm, settings.seeds)
    solver = SnoptSolver()
    wide = _wide(arm)
    found: list[np.ndarray] = []
    for value in fixed_values:
        ik = InverseKinematics(arm.plant, with_joint_limits=False)
        q_var = ik.q()[arm.position_starts]
        p = X_WF_target.translation()
        world = arm.plant.world_frame()
        ik.AddPositionConstraint(
            arm.flange_frame,
            np.zeros(3),
            world,
            p - SOLVER_POSITION_TOLERANCE_M,
            p + SOLVER_POSITION_TOLERANCE_M,
        )
        ik.AddOrientationConstraint(
            world,
            X_WF_target.rotation(),
            arm.flange_frame,
            RotationMatrix(),
            SOLVER_ORIENTATION_TOLERANCE_RAD,
        )
        prog = ik.get_mutable_prog()
        lower, upper = arm.lower.copy(), arm.upper.copy()
        if value is not None:
            lower[r] = upper[r] = value
        prog.AddBoundingBoxConstraint(lower, upper, q_var)
        for seed in seeds:
            q0 = seed.copy()
            if value is not None:
                q0[r] = value
            result = solver.Solve(prog, arm.plant_positions(q0), None)
            if not result.is_success():
                continue
            q, error = _polish(arm, result.GetSolution(ik.q())[arm.position_starts], X_WF_target,
                               free)  # fmt: skip
            q = _within_limits(arm, q)
            if (
                q is None
                or np.linalg.norm(error[:3]) > settings.orientation_tolerance_rad
                or np.linalg.norm(error[3:]) > settings.position_tolerance_m
            ):
                continue
            if not any(_same(q, s, wide, settings.distinct_tolerance) for s in found):
                found.append(q)
    if settings.turn_variants:
        found = [v for q in found for v in _turn_variants(arm, q)]
    if not found:
        return np.zeros((0, n))
    solutions = np.array(found)
    return solutions[np.lexsort(solutions.T[::-1])]

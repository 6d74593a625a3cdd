"""Planning: every returned trajectory is exact at its ends, within the limits and collision-free
under an independent dense check; bad input is reported; the roadmap cache is keyed correctly."""

import dataclasses
import math

import numpy as np
import pytest

from planners.collision import CollisionChecker
from planners.ik import Viewpoint, camera_pose, ik_camera, look_at_rotation, rig_centre_offset
from planners.planner import (
    PLAN_FAILURE_REASONS,
    PlanFailure,
    Planner,
    PlannerConfig,
    Trajectory,
)
from planners.prm import cache_path
from planners.timing import time_parameterise
from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import default_stereo_camera
from robots.arms.default import DEFAULT_ARM
from robots.arms.rx60 import RX60, rx60_arm
from robots.models.camera_tool import nominal_X_FC
from robots.models.workcell import WorkcellConfig, build_workcell
from robots.simulation.cell import HOME_Q
from robots.simulation.robot import SimulatedRobot

# Issue 3: the independent check samples at <= 0.25 deg per joint.
MAX_STEP_RAD = math.radians(0.25)
# Finite differences at sub-millisecond steps approximate the true derivatives to well within
# these relative margins.
VELOCITY_SLACK = 1.01
ACCELERATION_SLACK = 1.05
# Small budgets: the tests check behaviour, not roadmap quality.
SMALL = dict(roadmap_milestones=120, prm_build_time_s=20.0, query_time_s=0.5)
TINY = dict(roadmap_milestones=20, prm_build_time_s=10.0, query_time_s=0.2)


def rig():
    stereo = default_stereo_camera()
    return nominal_X_FC(stereo.baseline_m), stereo.X_CR


def make_planner(cell: WorkcellConfig, **config) -> Planner:
    X_FC, X_CR = rig()
    return Planner(build_workcell(cell, None, X_FC, X_CR), X_FC, X_CR, PlannerConfig(**config))


@pytest.fixture(scope="session")
def planner(tmp_path_factory):
    return make_planner(WorkcellConfig(), cache_dir=str(tmp_path_factory.mktemp("rm")), **SMALL)


@pytest.fixture(scope="session")
def independent_checker(planner):
    """A separately built cell and checker: the recheck trusts nothing of the planner's."""
    X_FC, X_CR = rig()
    cell = build_workcell(WorkcellConfig(), None, X_FC, X_CR)
    return CollisionChecker(cell, planner.config.padding_m, planner.config.edge_step_rad)


def sphere_viewpoint(azimuth_deg: float, elevation_deg: float, radius_m: float = 0.5):
    c = np.array(WorkcellConfig().object_center_m)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    d = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    return Viewpoint(tuple(c + radius_m * d), tuple(c), 0.0)


@pytest.fixture(scope="session")
def views(planner):
    """Reachable look-at views on the 0.5 m sphere: with the default cell, a cap below the
    object (elevation ~-82..-13 deg, all azimuths)."""
    out = []
    for az in range(0, 360, 40):
        for el in (-60, -40, -20):
            qs = planner.reachable(sphere_viewpoint(az, el), HOME_Q)
            if qs:
                out.append(qs)
    assert len(out) >= 6
    return out


def recheck(trajectory: Trajectory, q_start, q_goal, checker: CollisionChecker) -> None:
    """Independent dense check: uniform time samples fine enough for <= 0.25 deg steps at the
    fastest joint speed, finite-difference velocities and accelerations, a separate checker."""
    robot = RX60()
    v = np.array(robot.velocity_limits_rad_s)
    a = np.array(robot.acceleration_limits_rad_s2)
    assert np.array_equal(trajectory.sample(0.0), q_start)
    assert np.array_equal(trajectory.sample(trajectory.duration_s), q_goal)
    dt = MAX_STEP_RAD / v.max()
    n = max(3, math.ceil(trajectory.duration_s / dt) + 1)
    t = np.linspace(0.0, trajectory.duration_s, n)
    q = trajectory.samples(t)
    assert np.abs(np.diff(q, axis=0)).max() <= MAX_STEP_RAD
    assert np.all(q >= robot.lower) and np.all(q <= robot.upper)
    h = t[1] - t[0]
    qd = np.diff(q, axis=0) / h
    qdd = np.diff(q, 2, axis=0) / h**2
    assert np.all(np.abs(qd) <= VELOCITY_SLACK * v)
    assert np.all(np.abs(qdd) <= ACCELERATION_SLACK * a)
    assert checker.are_free(q).all()
    # What a driver executes: exact ends, strictly increasing times.
    jt = trajectory.to_joint_trajectory(0.01)
    assert np.array_equal(jt.positions_rad[0], q_start)
    assert np.array_equal(jt.positions_rad[-1], q_goal)
    assert jt.duration_s == pytest.approx(trajectory.duration_s)


def straight_line_collides(planner: Planner, q_a, q_b) -> bool:
    return not planner.checker.edge_free(q_a, q_b)


# --- configurations ----------------------------------------------------------------------------


def test_home_and_look_at_configurations_are_free_with_10mm_padding(planner, views):
    assert planner.config.padding_m == pytest.approx(0.010)
    assert planner.is_collision_free(HOME_Q)
    assert all(planner.is_collision_free(qs[0]) for qs in views)


def test_reachable_solutions_are_free_and_ordered_by_motion_time(planner):
    vp = sphere_viewpoint(180, -20)
    rolls = np.radians([-30, 0, 30]).tolist()
    qs = planner.reachable(vp, HOME_Q, rolls)
    assert len(qs) >= 2
    assert all(planner.is_collision_free(q) for q in qs)
    times = [planner.estimate_duration_s(HOME_Q, q) for q in qs]
    assert times == sorted(times)
    # Each one puts the LEFT camera where one of the rolls asks for it.
    X_FC, X_CR = rig()
    wanted = [
        camera_pose(dataclasses.replace(vp, roll_rad=r), rig_centre_offset(X_CR)) for r in rolls
    ]
    for q in qs:
        assert any(
            any(np.allclose(q, s, atol=1e-9) for s in ik_camera(rx60_arm(), X_WC, X_FC))
            for X_WC in wanted
        )


# --- plans -------------------------------------------------------------------------------------


def test_trajectories_between_look_at_views_pass_the_independent_check(
    planner, views, independent_checker
):
    rng = np.random.default_rng(3)
    for _ in range(6):
        a, b = rng.choice(len(views), size=2, replace=False)
        q_start = views[a][rng.integers(len(views[a]))]
        q_goal = min(views[b], key=lambda q: planner.estimate_duration_s(q_start, q))
        result = planner.plan(q_start, q_goal)
        assert isinstance(result, Trajectory), result
        recheck(result, q_start, q_goal, independent_checker)
        assert planner.estimate_duration_s(q_start, q_goal) <= result.duration_s + 1e-9


def _blocked_pair(planner, views):
    """Two look-at configurations whose straight joint-space move collides, or None."""
    pairs = [
        (qa, qb)
        for i, qs_a in enumerate(views)
        for qs_b in views[i + 1 :]
        for qa in qs_a[:3]
        for qb in qs_b[:3]
    ]
    return next(((a, b) for a, b in pairs if straight_line_collides(planner, a, b)), None)


def test_a_blocked_straight_move_is_routed_around(planner, views, independent_checker):
    blocked = _blocked_pair(planner, views)
    if blocked is None:
        pytest.skip("every straight move between these views is free")
    result = planner.plan(*blocked)
    assert isinstance(result, Trajectory), result
    assert result.stats.method in ("roadmap", "rrtconnect")
    assert len(result.path_rad) >= 3
    recheck(result, *blocked, independent_checker)


def test_trajectory_executes_on_the_simulated_robot(planner, views):
    q_start, q_goal = views[0][0], views[-1][0]
    result = planner.plan(q_start, q_goal)
    assert isinstance(result, Trajectory), result
    arm = SimulatedRobot(DEFAULT_ARM, np.zeros(6), q_start)
    arm.execute(result.to_joint_trajectory())
    assert np.array_equal(arm.joint_positions(), q_goal)


@pytest.mark.parametrize("dq_rad", [0.0, 1e-15, 1e-9, 1e-7, 2e-6, 1e-4])
def test_tiny_moves_and_holds_are_exact_and_at_rest(planner, independent_checker, dq_rad):
    q_goal = HOME_Q.copy()
    q_goal[[0, 5]] += dq_rad
    result = planner.plan(HOME_Q, q_goal)
    assert isinstance(result, Trajectory), result
    recheck(result, HOME_Q, q_goal, independent_checker)
    jt = result.to_joint_trajectory(0.01)
    assert len(jt.times_s) >= 2
    assert np.array_equal(jt.positions_rad[0], HOME_Q)
    assert np.array_equal(jt.positions_rad[-1], q_goal)


# --- failures and bad input --------------------------------------------------------------------


def goal_inside_the_object(planner):
    """The left camera 0.1-0.15 m below the object's centre, looking at it: inside the keep-out."""
    centre = np.array(WorkcellConfig().object_center_m)
    X_FC, _ = rig()
    for offset in (0.10, 0.12, 0.15):
        X_WC = np.eye(4)
        X_WC[:3, 3] = centre - np.array([0.0, 0.0, offset])
        X_WC[:3, :3] = look_at_rotation(X_WC[:3, 3], centre)
        solutions = ik_camera(rx60_arm(), X_WC, X_FC)
        if solutions:
            return solutions[0]
    raise AssertionError("no configuration puts the camera inside the object")


def test_goal_inside_an_obstacle_is_reported_not_planned(planner, views):
    q_goal = goal_inside_the_object(planner)
    assert not planner.is_collision_free(q_goal)
    result = planner.plan(views[0][0], q_goal)
    assert isinstance(result, PlanFailure)
    assert result.reason == "goal_invalid"
    assert "collision" in result.detail


def test_no_path_is_reported(planner, views, monkeypatch):
    """With every motion blocked, the roadmap and RRTConnect both fail: "no_path"."""
    monkeypatch.setattr(planner.checker, "edge_free", lambda q_a, q_b: False)
    monkeypatch.setattr(planner, "config", dataclasses.replace(planner.config, query_time_s=0.05))
    result = planner.plan(views[0][0], views[-1][0])
    assert isinstance(result, PlanFailure) and result.reason == "no_path"


def test_invalid_starts_are_reported(planner, views):
    outside = HOME_Q.copy()
    outside[0] = math.radians(170)  # J1 range is +-160 deg
    result = planner.plan(outside, views[0][0])
    assert isinstance(result, PlanFailure) and result.reason == "start_invalid"
    assert "joint limits" in result.detail
    result = planner.plan(goal_inside_the_object(planner), views[0][0])
    assert isinstance(result, PlanFailure) and result.reason == "start_invalid"
    assert result.reason in PLAN_FAILURE_REASONS


@pytest.mark.parametrize(
    "q", [np.full(6, np.nan), np.array([0.0, 0.1, np.inf, 0, 0, 0]), np.zeros(5)]
)
def test_malformed_configurations_raise_a_user_error(planner, q):
    with pytest.raises(ScannerError):
        planner.plan(q, HOME_Q)
    with pytest.raises(ScannerError):
        planner.plan(HOME_Q, q)
    with pytest.raises(ScannerError):
        planner.is_collision_free(q)


def test_bad_viewpoints_raise_a_user_error(planner):
    c = np.array(WorkcellConfig().object_center_m)
    inside = Viewpoint(tuple(c + [0.05, 0, 0]), tuple(c), 0.0)
    looking_away = Viewpoint(tuple(c + [-0.5, 0, 0]), tuple(c + [-1.0, 0, 0]), 0.0)
    not_finite = Viewpoint((np.nan, 0.0, 0.5), tuple(c), 0.0)
    for vp in (inside, looking_away, not_finite):
        with pytest.raises(ScannerError):
            planner.reachable(vp, HOME_Q)
    with pytest.raises(ScannerError):
        planner.reachable(sphere_viewpoint(180, -20), HOME_Q, [math.nan])


def test_planner_config_is_validated():
    for bad in (
        dict(padding_m=-0.01),
        dict(padding_m=math.nan),
        dict(roadmap_milestones=0),
        dict(edge_step_rad=math.radians(1.0)),
        dict(max_joint_step_rad=math.radians(0.5)),
        dict(toppra_limit_fraction=1.5),
        dict(seed=0),
    ):
        with pytest.raises(ScannerError):
            PlannerConfig(**bad)
    with pytest.raises(ValueError):
        PlanFailure("because", "not a documented reason")


# --- the validation itself ---------------------------------------------------------------------


def test_validation_rejects_collisions_and_limit_violations(planner, views):
    pairs = [(a[0], b[0]) for i, a in enumerate(views) for b in views[i + 1 :]]
    blocked = next(((a, b) for a, b in pairs if straight_line_collides(planner, a, b)), None)
    if blocked is not None:
        straight = time_parameterise(
            np.array(blocked), planner.workcell.plant, rx60_arm(), "stop", 20, 0.95
        )
        report = planner.validate(straight, *blocked)
        assert not report.ok and report.failed_check == "collision"
    q_start, q_goal = views[0][0], views[-1][0]
    result = planner.plan(q_start, q_goal)
    assert isinstance(result, Trajectory)
    assert planner.validate(result, q_start, q_goal).ok
    too_fast = time_parameterise(
        result.path_rad, planner.workcell.plant, rx60_arm(), result.corners, 20, 1.5
    )
    report = planner.validate(too_fast, q_start, q_goal)
    assert not report.ok and report.failed_check in ("velocity_limit", "acceleration_limit")
    assert planner.validate(result, q_goal, q_start).failed_check == "endpoints"


# --- the roadmap cache -------------------------------------------------------------------------


def test_cache_is_reused_and_rebuilt_when_the_cell_changes(tmp_path):
    cache = str(tmp_path)
    first = make_planner(WorkcellConfig(), cache_dir=cache, **TINY)
    assert not first.roadmap_from_cache
    assert cache_path(tmp_path, first.roadmap_key).exists()
    second = make_planner(WorkcellConfig(), cache_dir=cache, **TINY)
    assert second.roadmap_from_cache
    assert np.array_equal(second.roadmap.vertices_rad, first.roadmap.vertices_rad)
    assert np.array_equal(second.roadmap.edges, first.roadmap.edges)
    moved = make_planner(WorkcellConfig(object_center_m=(0.32, 0.0, 0.78)), cache_dir=cache, **TINY)
    assert not moved.roadmap_from_cache and moved.roadmap_key != first.roadmap_key
    bigger = make_planner(WorkcellConfig(object_size_m=0.25), cache_dir=cache, **TINY)
    assert not bigger.roadmap_from_cache
    padded = make_planner(WorkcellConfig(), cache_dir=cache, padding_m=0.02, **TINY)
    assert not padded.roadmap_from_cache
    assert len({first.roadmap_key, moved.roadmap_key, bigger.roadmap_key, padded.roadmap_key}) == 4
    # Query-time settings do not invalidate the roadmap.
    faster = make_planner(WorkcellConfig(), cache_dir=cache, shortcut_steps=2, **TINY)
    assert faster.roadmap_from_cache


def test_a_damaged_cache_file_is_never_used(tmp_path):
    first = make_planner(WorkcellConfig(), cache_dir=str(tmp_path), **TINY)
    path = cache_path(tmp_path, first.roadmap_key)
    path.write_bytes(path.read_bytes()[:100])
    again = make_planner(WorkcellConfig(), cache_dir=str(tmp_path), **TINY)
    assert not again.roadmap_from_cache
    # The rebuilt roadmap replaced the damaged file, atomically and with no temporary left.
    assert make_planner(WorkcellConfig(), cache_dir=str(tmp_path), **TINY).roadmap_from_cache
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


# --- what a point-to-point controller runs --------------------------------------------------


def test_a_joint_linear_controller_gets_waypoints_checked_as_straight_moves(
    planner, views, independent_checker
):
    """The VAL 3 server moves straight in joint space between points: the waypoints hug the
    validated curve (every chord within the tolerance of it) and their own polyline is free
    under an independent checker at the dense resolution."""
    from planners.joint_linear import chord_deviation_rad, polyline_samples

    pair = _blocked_pair(planner, views) or (views[0][0], views[-1][0])
    result = planner.plan(*pair)
    assert isinstance(result, Trajectory), result
    jt = planner.executable(result, "joint_linear")
    assert jt.joint_linear and not planner.executable(result, "sampled").joint_linear
    q = jt.positions_rad
    assert np.array_equal(q[0], pair[0]) and np.array_equal(q[-1], pair[1])
    # Far fewer points than the 10 ms samples a sampled driver plays (the arm stops at each).
    assert 2 <= len(q) < len(result.to_joint_trajectory().positions_rad) / 3
    tolerance = planner.config.chord_tolerance_rad
    for k in range(len(q) - 1):
        t = np.linspace(jt.times_s[k], jt.times_s[k + 1], 50)
        assert chord_deviation_rad(result.samples(t), q[k], q[k + 1]).max() <= tolerance + 1e-12
    dense = polyline_samples(q, MAX_STEP_RAD)
    assert np.abs(np.diff(dense, axis=0)).max() <= MAX_STEP_RAD + 1e-12
    assert independent_checker.are_free(dense).all()


def test_a_straight_move_through_the_cell_is_refused_for_a_joint_linear_controller(planner, views):
    """With a chord tolerance so large that the controller would be sent straight from start to
    goal, the polyline check finds the collision the curve went around: nothing to execute."""
    from planners.joint_linear import joint_linear_trajectory, validate_polyline

    pair = _blocked_pair(planner, views)
    if pair is None:
        pytest.skip("every straight move between these views is free")
    result = planner.plan(*pair)
    assert isinstance(result, Trajectory), result
    report = validate_polyline(np.stack(pair), *pair, planner.checker, planner.arm, MAX_STEP_RAD)
    assert not report.ok and report.failed_check == "collision"
    refused = joint_linear_trajectory(result, planner.checker, planner.arm, 10.0, MAX_STEP_RAD)
    assert not refused.ok and refused.failed_check == "collision"

"""`scanner scan --plan-only`: the scan's viewpoints, tour and motions planned exactly as a scan
plans them (same generator, same tour, the decision maker's order of options, the same planner
calls), without moving the arm, capturing or reconstructing; the plan goes to plan.json and a
picture of the cell to plan.png."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from planners.ik import Viewpoint, camera_pose, ik_camera
from planners.planner import PlanFailure, Planner
from planners.tour import plan_tour
from reconstruction.common.errors import ScannerError
from reconstruction.common.sphere import fibonacci_directions
from robots.models.kinematics import Kinematics
from robots.models.workcell import keep_out_radius_m
from scanner.configs.scan import ScanConfig
from scanner.configs.views import ViewpointConfig
from scanner.plan_only.records import PlannedViewpoint, ScanPlan
from scanner.scan.decision import FixedViewList
from scanner.scan.world import ScanWorld, setup_world
from scanner.scan_dir.outputs import PLAN_FILE  # written last: it marks a finished plan
from scanner.scan_dir.results_folder import holds_result, staged_folder
from scanner.scan_dir.views import PlannedView

PICTURE_FILE = "plan.png"


def _rolls_rad(config: ViewpointConfig) -> np.ndarray:
    """The set of camera rolls the view generator tries (its order does not matter here)."""
    return 2 * math.pi * np.arange(config.roll_candidates) / config.roll_candidates


def why_unreachable(
    planner: Planner, centre: np.ndarray, direction: np.ndarray, config: ViewpointConfig, q_seed
) -> tuple[str, str, np.ndarray] | None:
    """(reason, detail, X_WC at zero roll) of a direction no configuration reaches: no joint
    solution at any roll, or every solution in collision (the closest pair named); None when a
    collision-free solution exists (the planner's `reachable` test, over every roll)."""
    p_WM = centre + config.radius_m * direction
    poses = [
        camera_pose(Viewpoint(tuple(p_WM), tuple(centre), float(r)), planner.X_MC)
        for r in _rolls_rad(config)
    ]
    solutions = [q for X_WC in poses for q in ik_camera(planner.arm, X_WC, planner.X_FC, q_seed)]
    if not solutions:
        return (
            "no_ik_solution",
            f"no joint solution within the limits at any of {len(poses)} rolls (out of reach)",
            poses[0],
        )
    if any(planner.checker.are_free(solutions)):
        return None
    return (
        "in_collision",
        f"all {len(solutions)} joint solutions collide; the first is "
        + planner.checker.describe(solutions[0]),
        poses[0],
    )


def _dropped(world: ScanWorld, config: ScanConfig, plan, q_home) -> list[PlannedViewpoint]:
    """The generator's dropped views, with the reason found again for each direction."""
    centre = np.asarray(config.scan_center_m, float)
    out = []
    for d in plan.dropped:
        if d.direction is None:
            missing = config.views.count - len(plan.views)
            shortfall = _unreached(None, None, ("too_few_reachable_directions", d.reason, None))
            out += [shortfall] * missing
            continue
        direction = np.asarray(d.direction, float)
        why = why_unreachable(world.planner, centre, direction, config.views, q_home)
        # The diagnosis tries the generator's rolls with the planner's checks, so it finds no
        # free solution either; should they ever disagree, the generator's own words are kept.
        out.append(_unreached(None, direction, why or ("no_ik_solution", d.reason, None)))
    return out


def _unreached(index, direction, why: tuple) -> PlannedViewpoint:
    reason, detail, X_WC = why
    return PlannedViewpoint(index, 0, None, direction, X_WC, None, False, reason, detail)


def _nothing_reachable(
    world: ScanWorld, config: ScanConfig, q_home
) -> list[PlannedViewpoint] | None:
    """When no candidate direction is reachable (the generator refuses): the views a sphere
    distribution would take, each with its reason; None if one of them is reachable after all
    (then the generator's error stands)."""
    v = config.views
    centre = np.asarray(config.scan_center_m, float)
    directions = fibonacci_directions(
        v.count, math.sin(v.elevation_min_rad), math.sin(v.elevation_max_rad)
    )
    out = []
    for d in directions:
        why = why_unreachable(world.planner, centre, d, v, q_home)
        if why is None:
            return None
        out.append(_unreached(None, d, why))
    return out


def _visit(planner: Planner, views: FixedViewList, view: PlannedView, q_now: np.ndarray):
    """The decision maker's PLAN state for one view: its options in order until one plans.
    Returns (trajectory or None, the failures' reason codes and details)."""
    failures: list[PlanFailure] = []
    for option in views.options_in_order(view):
        result = planner.plan(q_now, option.q)
        if not isinstance(result, PlanFailure):
            return result, failures
        failures.append(result)
    return None, failures


def _plan_pass(
    world: ScanWorld, todo: list[PlannedView], hanging: int, q_now, first_order: int, kin
) -> tuple[list[PlannedViewpoint], np.ndarray]:
    """One hanging's tour from q_now and its moves; returns the viewpoints and where the arm
    would end."""
    planner = world.planner
    tour = plan_tour(q_now, todo, planner.estimate_duration_s)
    ordered = [todo[k] for k in tour.order]
    views = FixedViewList(list(ordered), {todo[k].index: tour.option[k] for k in range(len(todo))})
    out = []
    for position, view in enumerate(ordered, start=first_order):
        trajectory, failures = _visit(planner, views, view, q_now)
        if trajectory is None:
            # Not reached: the pose asked for, and why each option failed; the arm stays put.
            X_WC = camera_pose(view.viewpoint, planner.X_MC)
            q_rad, motion_s = None, 0.0
            reason = failures[0].reason
            detail = "planning failed for every option: " + "; ".join(
                f"{f.reason}: {f.detail}" for f in failures
            )
        else:
            # Where the executed trajectory ends (its last sample), as the arm would report it.
            q_now = trajectory.to_joint_trajectory().positions_rad[-1].copy()
            X_WC = kin.X_WF(q_now) @ world.X_FC
            q_rad, motion_s = q_now, float(trajectory.duration_s)
            reason = detail = ""
        out.append(
            PlannedViewpoint(
                view.index,
                hanging,
                position,
                view.direction,
                X_WC,
                q_rad,
                reachable=trajectory is not None,
                reason=reason,
                detail=detail,
                motion_s=motion_s,
            )
        )
    return out, q_now


def plan_scan(config: ScanConfig, world: ScanWorld) -> ScanPlan:
    """The plan of a new scan on `world`; reads the arm's joints, never moves it."""
    from scanner.scan.run import new_scan_views

    q_home = world.robot.joint_positions()
    try:
        plan, views = new_scan_views(config, world)
    except ScannerError:
        unreachable = _nothing_reachable(world, config, q_home)
        if unreachable is None:
            raise
        plan, views = None, []
    viewpoints: list[PlannedViewpoint] = []
    q_now = q_home
    count = len(views) // config.first_hangings
    dropped = _dropped(world, config, plan, q_home) if plan is not None else unreachable
    kinematics = Kinematics(world.arm)
    for p in range(config.first_hangings):
        todo = views[p * count : (p + 1) * count]
        first = 1 + sum(v.order is not None for v in viewpoints)
        visited, q_now = _plan_pass(world, todo, p, q_now, first, kinematics)
        # A view dropped by the generator is missing from every hanging.
        in_hanging = visited + [replace(v, hanging=p) for v in dropped]
        viewpoints += [replace(v, number=k) for k, v in enumerate(in_hanging, start=1)]
    return ScanPlan(
        tuple(viewpoints),
        np.asarray(config.scan_center_m, float),
        keep_out_radius_m(config.cell),
        config.first_hangings,
        config.views.max_extra_views,
    )


def plan_to_dict(plan: ScanPlan, config: ScanConfig) -> dict:
    """plan.json: SI units, poses as 4x4 row-major lists."""

    def listed(a):
        return None if a is None else np.asarray(a).tolist()

    return {
        "object": config.object,
        "views_requested": len(plan.viewpoints),
        "views_reachable": plan.reachable_count,
        "estimated_robot_time_s": plan.robot_time_s,
        "hangings": plan.hangings,
        "next_best_views_not_planned_per_hanging": plan.extra_views_not_planned,
        "scan_center_m": listed(plan.scan_center_m),
        "radius_m": config.views.radius_m,
        "keep_out_radius_m": plan.keep_out_radius_m,
        "picture": PICTURE_FILE,
        "viewpoints": [
            {
                "index": v.index,
                "number": v.number,
                "hanging": v.hanging,
                "order": v.order,
                "reachable": v.reachable,
                "reason": v.reason or None,
                "detail": v.detail or None,
                "motion_s": v.motion_s,
                "direction": listed(v.direction),
                "X_WC": listed(v.X_WC),
                "q_rad": listed(v.q_rad),
            }
            for v in plan.viewpoints
        ],
    }


def require_plan_folder(out: Path, force: bool) -> None:
    """Refuse, before planning, a folder that holds anything but a plan, or a plan without
    --force."""
    out = Path(out)
    if not out.is_dir() or not any(out.iterdir()):
        return
    if not holds_result(out, PLAN_FILE):
        raise ScannerError(f"{out}: exists and is not a plan folder; choose another --out")
    if not force:
        raise ScannerError(
            f"{out}: holds a plan already; choose another --out, or --force to replace it"
        )


@dataclass(frozen=True, eq=False)
class PlanRun:
    plan: ScanPlan
    out: Path

    @property
    def picture(self) -> Path:
        return self.out / PICTURE_FILE


def run_plan_only(config: ScanConfig, out: Path, force: bool = False) -> PlanRun:
    """Plan the scan `config` asks for and write plan.json and plan.png into `out`."""
    from scanner.plan_only.picture import draw_plan
    from scanner.scan.layout import laid_out

    require_plan_folder(out, force)
    config = laid_out(config)
    world = setup_world(config)
    plan = plan_scan(config, world)
    with staged_folder(Path(out), PLAN_FILE) as staging:
        draw_plan(plan, config.cell, staging / PICTURE_FILE)
        text = json.dumps(plan_to_dict(plan, config), indent=2) + "\n"
        (staging / PLAN_FILE).write_text(text)
    return PlanRun(plan, Path(out))


def summary_lines(run: PlanRun) -> list[str]:
    """One line per unreachable viewpoint, then the totals and the picture."""
    lines = [
        f"unreachable: view {v.number}{_in_hanging(run.plan, v)}: {v.reason}: {v.detail}"
        for v in run.plan.unreachable
    ]
    if run.plan.extra_views_not_planned:
        lines.append(
            f"not planned: up to {run.plan.extra_views_not_planned} next-best views per hanging "
            "(chosen from the captures during the scan)"
        )
    lines.append(
        f"plan: views reachable {run.plan.reachable_count} of {len(run.plan.viewpoints)}, "
        f"estimated robot time {run.plan.robot_time_s:.1f} s, picture {run.picture}"
    )
    return lines


def _in_hanging(plan: ScanPlan, v: PlannedViewpoint) -> str:
    return f" (hanging {v.hanging + 1})" if plan.hangings > 1 else ""


def plan_command(config: ScanConfig, out: Path, force: bool) -> int:
    """Plan, write and print; a plan that reaches fewer views than asked is a user error (exit
    2) naming the views, after its files are written (they show where the views are)."""
    run = run_plan_only(config, out, force)
    for line in summary_lines(run):
        print(line)
    missing = run.plan.unreachable
    if missing:
        numbers = ", ".join(f"{v.number}{_in_hanging(run.plan, v)}" for v in missing)
        raise ScannerError(
            f"--plan-only: {len(missing)} of {len(run.plan.viewpoints)} views are unreachable: "
            f"view {numbers} (numbered in {run.picture}; the reasons above and in "
            f"{run.out / PLAN_FILE})"
        )
    return 0

"""`scanner scan --plan-only`: the plan is the scan's own (views, order, poses, robot time), it
never moves the arm nor writes captures, and views out of reach are listed with their reason."""

import copy
import dataclasses
import json
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml

from planners.ik import rig_centre_offset
from robots.models.workcell import DEFAULT_CELL_BOXES
from scanner.commands.main import main
from scanner.configs.scan import scan_config_from_dict
from scanner.plan_only.plan import PICTURE_FILE, PLAN_FILE, plan_scan, run_plan_only
from scanner.scan.run import run_scan
from scanner.scan.world import setup_world
from scanner.scan_dir.captures import CaptureStore
from tests.tiny_scan import TINY_SCAN

# Capture-only: the comparison is about where the arm goes, not the model.
TINY = {**copy.deepcopy(TINY_SCAN), "reconstruct": False}
# The RX60 wrist centre reaches at most this far from the shoulder (upper arm + forearm with the
# elbow offset, Staubli RX60 datasheet lengths in robots.arms.rx60).
SHOULDER_TO_WRIST_MAX_M = float(np.hypot(0.290 + 0.310, 0.049))
SHOULDER_M = np.array([0.0, 0.0, 0.341])


def _config(**changes):
    data = copy.deepcopy(TINY)
    for section, values in changes.items():
        data[section] = {**data.get(section, {}), **values}
    return scan_config_from_dict(data, "test")


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


@pytest.fixture(scope="module")
def plan_and_scan(tmp_path_factory):
    """The plan of the tiny scan, then the scan itself with the same configuration."""
    root = tmp_path_factory.mktemp("plan")
    config = _config()
    plan_run = run_plan_only(config, root / "plan")
    scan = run_scan(config, root / "scan")
    return plan_run, scan


def test_plan_is_what_the_scan_then_does(plan_and_scan):
    plan_run, scan = plan_and_scan
    plan = plan_run.plan
    store = CaptureStore.open(scan.scan_dir)
    captures = sorted(
        (store.read_capture(i) for i in store.captured_indices()), key=lambda c: c.stamp_s
    )
    visited = sorted((v for v in plan.viewpoints if v.reachable), key=lambda v: v.order)
    assert plan.reachable_count == len(captures) == 5
    assert [v.index for v in visited] == [c.pose_index for c in captures]
    assert [v.order for v in visited] == [1, 2, 3, 4, 5]
    X_FC = np.array(store.read_manifest()["X_FC_nominal"])
    for v, c in zip(visited, captures):
        # The same joint configuration: the pose agrees to rounding.
        np.testing.assert_allclose(v.q_rad, c.q_rad, atol=1e-12)
        np.testing.assert_allclose(v.X_WC, c.X_WF @ X_FC, atol=1e-9)
    # The plan makes the scan's planner calls in the scan's order on a planner seeded alike, so
    # every move has the same duration; the sums agree to rounding (RRTConnect, whose result
    # depends on its time budget, is not needed by these moves).
    assert plan.robot_time_s == pytest.approx(scan.report["robot_motion_s"], abs=1e-6)
    assert plan.robot_time_s > 1.0  # five moves of the RX60 between views


def test_plan_files(plan_and_scan):
    plan_run, _ = plan_and_scan
    out = plan_run.out
    assert sorted(p.name for p in out.iterdir()) == [PLAN_FILE, PICTURE_FILE]  # no captures
    assert _png_size(out / PICTURE_FILE) == (1400, 700)
    assert (out / PICTURE_FILE).stat().st_size > 20_000  # a drawing, not an empty canvas
    saved = json.loads((out / PLAN_FILE).read_text())
    assert saved["views_reachable"] == 5 and saved["views_requested"] == 5
    assert saved["estimated_robot_time_s"] == pytest.approx(plan_run.plan.robot_time_s)
    X_MC = rig_centre_offset(_config().camera.stereo_camera().X_CR)
    for entry, v in zip(saved["viewpoints"], plan_run.plan.viewpoints):
        X_WC = np.array(entry["X_WC"])
        np.testing.assert_allclose(X_WC, v.X_WC, atol=0)
        # The rig centre M looks straight at the scan centre from the configured 0.5 m (to the
        # IK's 1e-7 verification tolerance).
        X_WM = X_WC @ np.linalg.inv(X_MC)
        to_centre = np.array(saved["scan_center_m"]) - X_WM[:3, 3]
        assert np.linalg.norm(to_centre) == pytest.approx(0.5, abs=1e-6)
        np.testing.assert_allclose(to_centre / 0.5, X_WM[:3, 2], atol=1e-6)
        assert entry["reachable"] and entry["reason"] is None and entry["motion_s"] > 0


def test_planning_never_moves_the_arm():
    config = _config()
    world = setup_world(config)
    q0 = world.robot.joint_positions()
    plan = plan_scan(config, world)
    assert plan.reachable_count == 5
    assert world.sim.robot.executed == [] and world.sim.robot.motion_time_s == 0.0
    np.testing.assert_array_equal(world.robot.joint_positions(), q0)


def test_out_of_reach_views_are_listed_with_their_reason(tmp_path, monkeypatch, capsys):
    config_file = tmp_path / "tiny.yaml"
    config_file.write_text(yaml.safe_dump(TINY))
    monkeypatch.chdir(tmp_path)
    # 1.2 m from the object centre is beyond the arm (the scan itself refuses to start).
    code = main(["scan", "--plan-only", "--config", str(config_file), "--radius", "1.2"])
    assert code == 2  # fewer views reachable than asked: the plan is written, then refused
    printed = capsys.readouterr()
    lines = printed.out.splitlines()
    assert len(lines) == 6
    assert all("unreachable" in line and "no_ik_solution" in line for line in lines[:5])
    (error,) = printed.err.splitlines()
    assert "5 of 5 views are unreachable: view 1, 2, 3, 4, 5" in error
    (out,) = (tmp_path / "scans").iterdir()
    assert out.name.startswith("vase-") and out.name.endswith("-plan")
    assert lines[5] == (
        "plan: views reachable 0 of 5, estimated robot time 0.0 s, "
        f"picture {out.relative_to(tmp_path) / PICTURE_FILE}"
    )
    assert sorted(p.name for p in out.iterdir()) == [PLAN_FILE, PICTURE_FILE]
    saved = json.loads((out / PLAN_FILE).read_text())
    assert saved["views_reachable"] == 0 and saved["estimated_robot_time_s"] == 0.0
    X_FC = _nominal_X_FC()
    for entry in saved["viewpoints"]:
        assert not entry["reachable"] and entry["reason"] == "no_ik_solution"
        # Ground truth: the wrist centre would have to be farther from the shoulder than the
        # arm's links reach.
        X_WF = np.array(entry["X_WC"]) @ np.linalg.inv(X_FC)
        p_WW = X_WF[:3, 3] - 0.065 * X_WF[:3, 2]
        assert np.linalg.norm(p_WW - SHOULDER_M) > SHOULDER_TO_WRIST_MAX_M


def _nominal_X_FC() -> np.ndarray:
    from robots.models import camera_tool

    return camera_tool.nominal_X_FC(_config().camera.stereo_camera().baseline_m)


def test_a_plan_short_of_views_exits_2_naming_them_as_plan_png_numbers_them(tmp_path, capsys):
    # Views on the whole sphere, none replaced by a neighbour: one of five is reachable.
    sphere = {"distribution": "sphere", "replace_within_rad": 1e-3}
    data = copy.deepcopy(TINY)
    data["views"] = {**data["views"], **sphere}
    config_file = tmp_path / "sphere.yaml"
    config_file.write_text(yaml.safe_dump(data))
    out = tmp_path / "plan"
    assert main(["scan", "--plan-only", "--config", str(config_file), "--out", str(out)]) == 2
    (error,) = capsys.readouterr().err.splitlines()
    saved = json.loads((out / PLAN_FILE).read_text())
    missing = [v["number"] for v in saved["viewpoints"] if not v["reachable"]]
    assert sorted(missing) == [2, 3, 4, 5]  # the reached view first, then the dropped ones
    assert f"4 of 5 views are unreachable: view {', '.join(map(str, missing))} " in error
    assert str(out / PICTURE_FILE) in error
    from scanner.plan_only.picture import UNREACHABLE_COLOUR, plan_figure

    plan = plan_scan(_config(views=sphere), setup_world(_config(views=sphere)))
    figure = plan_figure(plan, _config().cell)
    for axes in figure.axes:
        labels = {t.get_text(): t.get_color() for t in axes.texts if t.get_text().isdigit()}
        assert labels == {"1": "black", **{str(n): UNREACHABLE_COLOUR for n in missing}}


def test_a_view_blocked_by_an_obstacle_is_in_collision():
    # Views on the whole sphere, none replaced by a neighbour: only one of five is reachable.
    sphere = {"distribution": "sphere", "replace_within_rad": 1e-3}
    free = plan_scan(_config(views=sphere), setup_world(_config(views=sphere)))
    (reached,) = [v for v in free.viewpoints if v.reachable]
    assert [v.reason for v in free.viewpoints if not v.reachable] == ["no_ik_solution"] * 4
    # A post where that view's camera would be.
    post = {"name": "post", "p_WB": reached.X_WC[:3, 3].tolist(), "size": [0.06] * 3}
    boxes = [dataclasses.asdict(b) for b in DEFAULT_CELL_BOXES] + [post]
    blocked = _config(views=sphere, cell={"boxes": boxes})
    plan = plan_scan(blocked, setup_world(blocked))
    assert plan.reachable_count == 0 and plan.robot_time_s == 0.0
    (hit,) = [v for v in plan.viewpoints if v.reason == "in_collision"]
    np.testing.assert_allclose(hit.direction, reached.direction, atol=1e-12)
    assert "post" in hit.detail


def test_an_existing_plan_is_replaced_only_with_force(tmp_path, capsys):
    config_file = tmp_path / "tiny.yaml"
    config_file.write_text(yaml.safe_dump(TINY))
    out = tmp_path / "plan"
    args = ["scan", "--plan-only", "--config", str(config_file), "--radius", "1.2", "--out"]
    # Out of reach: each plan is written and the command exits 2 for the unreachable views.
    assert main([*args, str(out)]) == 2
    stamp = (out / PLAN_FILE).stat().st_mtime_ns
    capsys.readouterr()
    assert main([*args, str(out)]) == 2
    assert "holds a plan already" in capsys.readouterr().err
    assert (out / PLAN_FILE).stat().st_mtime_ns == stamp
    assert main([*args, str(out), "--force"]) == 2
    assert "views are unreachable" in capsys.readouterr().err
    assert (out / PLAN_FILE).stat().st_mtime_ns != stamp
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert main([*args, str(other), "--force"]) == 2
    assert "is not a plan" in capsys.readouterr().err
    assert (other / "notes.txt").read_text() == "mine"
    assert main(["scan", "--plan-only", "--resume", str(out)]) == 2

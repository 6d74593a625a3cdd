"""Presentations: the turntable in the cell (standing pose, the cell filter), known turns and the
axis they calibrate, the known turn as the alignment's start, the next-best turn, and a
turntable driver that does not answer or reports another angle (refused before anything
moves, or stopped and resumable during a scan)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from reconstruction.common.transforms import make_pose, rotation_about, transform_points
from reconstruction.hangings.alignment import align_pass, alignment_error
from reconstruction.hangings.free_space import SeenSpace
from reconstruction.hangings.turntable import Axis, KnownTurns, axis_from_turns, turn_about_axis
from robots.models.objects import resolve_object
from robots.models.turntable import turntable_geometry
from robots.models.workcell import WorkcellConfig
from tests import turntable_hardware
from tests.partial_clouds import partial_cloud, stripes
from tests.tiny_scan import TINY_SCAN

UP = np.array([0.0, 0.0, 1.0])
# A turntable mounted 1 mm and 0.1 deg off its drawing (the simulated one's largest errors).
TRUE_AXIS = Axis(
    np.array([0.4007, -0.0007, 0.9]), rotation_about(np.array([1.0, 1, 0]), 0.0017) @ UP
)
NOMINAL = Axis(np.array([0.4, 0.0, 0.9]), UP)


def test_the_axis_is_calibrated_from_two_turns():
    turns = [turn_about_axis(TRUE_AXIS.p_W, TRUE_AXIS.u_W, a) for a in (2.1, -1.7)]
    axis = axis_from_turns(turns, NOMINAL.p_W)
    assert abs(axis.u_W @ TRUE_AXIS.u_W) > 1 - 1e-12
    # On the true axis: no distance across it.
    d = axis.p_W - TRUE_AXIS.p_W
    assert np.linalg.norm(d - (d @ TRUE_AXIS.u_W) * TRUE_AXIS.u_W) < 1e-9
    # A turn too small to tell where the axis is calibrates nothing.
    assert (
        axis_from_turns([turn_about_axis(TRUE_AXIS.p_W, TRUE_AXIS.u_W, 0.01)], NOMINAL.p_W) is None
    )


def test_known_turns_start_about_the_nominal_axis_then_the_calibrated_one():
    angles = (0.3, 0.3 + 2.0, 0.3 - 1.5)
    turns = KnownTurns(angles, NOMINAL)
    # Pass h's points, seen after the object turned by angles[h] - angles[0], go back by it.
    truth = [turn_about_axis(TRUE_AXIS.p_W, TRUE_AXIS.u_W, angles[0] - a) for a in angles]
    p = np.array([[0.45, 0.02, 0.95], [0.38, -0.05, 1.05]])
    # Before calibration: off by what the axis error makes of a 2 rad turn (about 2 mm).
    nominal_error = np.abs(transform_points(turns.start(1), p) - transform_points(truth[1], p))
    assert 1e-4 < nominal_error.max() < 3e-3
    calibrated = turns.start(2, [(1, truth[1])])
    np.testing.assert_allclose(
        transform_points(calibrated, p), transform_points(truth[2], p), atol=1e-9
    )


def test_a_known_turn_verifies_without_the_search():
    # A 0.1 m pebble turned by 100 deg about the turntable's true axis; the start is the turn
    # about the nominal axis (1 mm, 0.1 deg off): ICP takes it to within the hanging tests'
    # bounds, and the verification passes with the one hypothesis.
    mesh = resolve_object("pebble", 0.1)
    X0 = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    X1 = turn_about_axis(TRUE_AXIS.p_W, TRUE_AXIS.u_W, math.radians(100)) @ X0
    ref, ref_colors = partial_cloud(mesh.vertices, mesh.triangles, X0, 0, stripes)
    moved, colors = partial_cloud(mesh.vertices, mesh.triangles, X1, 1, stripes)
    start = KnownTurns((0.0, math.radians(100)), NOMINAL).start(1)
    a = align_pass(
        1, moved, ref, SeenSpace((), ()), colors=colors, reference_colors=ref_colors, start=start
    )
    assert a.verified and a.from_known_turn and a.hypotheses == 1
    dt, dr = alignment_error(a.T, X0 @ np.linalg.inv(X1), transform_points(X1, mesh.vertices))
    assert dt < 0.5e-3 and math.degrees(dr) < 0.2


def test_the_object_stands_on_the_disc_and_the_cell_filter_removes_the_turntable():
    from reconstruction.stereo.camera_model import default_stereo_camera
    from robots.models.camera_tool import nominal_X_FC
    from robots.models.point_filter import make_geometry_filter
    from robots.models.workcell import build_workcell
    from robots.simulation.laying import first_lying_pose, stable_poses

    cell = WorkcellConfig()
    g = turntable_geometry(cell)
    mesh = resolve_object("pebble", cell.object_size_m)
    X = first_lying_pose(cell, mesh)
    v_W = transform_points(X, mesh.vertices)
    # Settled on the face underneath: nothing below the disc's top, its centre over the axis.
    assert v_W[:, 2].min() == pytest.approx(g.p_top_W[2], abs=1e-12)
    _, com_O = stable_poses(mesh)
    np.testing.assert_allclose(transform_points(X, com_O[None])[0, :2], g.p_top_W[:2], atol=1e-12)
    stereo = default_stereo_camera()
    X_FC = nominal_X_FC(stereo.baseline_m)
    workcell = build_workcell(cell, None, X_FC, stereo.X_CR, presentation="turntable")
    keep = make_geometry_filter(workcell, 0.003)
    x, y, top = g.p_top_W
    points = np.array(
        [
            [x + 0.02, y, top],  # on the disc
            [x, y + 0.01, 0.4],  # on the post
            [x + 0.02, y, top + 0.02],  # the object's bottom, 2 cm above the disc
            [x, y, cell.object_center_m[2] + 0.09],  # its top: no rod above a turntable
        ]
    )
    from robots.arms.default import DEFAULT_ARM

    assert keep(points, DEFAULT_ARM.home_q).tolist() == [False, False, True, True]


def _tiny_turntable(tmp_path, **extra) -> str:
    path = tmp_path / "turntable.yaml"
    config = {**TINY_SCAN, "presentation": "turntable", "hangings": 2, "reconstruct": False}
    path.write_text(yaml.safe_dump({**config, **extra}))
    return str(path)


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    return err


@pytest.mark.parametrize(
    ("factory", "words"),
    [
        ("lying", "reports 17.19 deg after being told 0.00 deg"),
        ("silent", "did not answer (TimeoutError"),
        ("no_turntable", "Hardware.turntable is None"),
    ],
)
def test_a_turntable_that_lies_or_is_silent_is_refused_before_anything_moves(
    tmp_path, capsys, factory, words
):
    from scanner.commands.main import main

    turntable_hardware.CELLS.clear()
    config = _tiny_turntable(tmp_path, driver=f"tests.turntable_hardware:{factory}")
    out = tmp_path / "scan"
    assert main(["scan", "--config", config, "--out", str(out)]) == 2
    assert words in _one_line_error(capsys)
    assert not out.exists()
    assert all(not cell.robot.executed for cell in turntable_hardware.CELLS)


def test_a_presentation_the_cell_has_no_model_for_is_refused(tmp_path, capsys):
    from reconstruction.common.errors import ScannerError
    from robots.models.workcell import check_presentation
    from scanner.commands.main import main

    out = tmp_path / "scan"
    config = _tiny_turntable(tmp_path, presentation="shelf")
    assert main(["scan", "--config", config, "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    assert "presentation" in err and "'shelf'" in err and "table" in err
    assert not out.exists()
    # The cell model's own check names the presentations it has a model for.
    with pytest.raises(
        ScannerError, match="no model for 'shelf'; it has hanging, turntable, table"
    ):
        check_presentation("shelf")


def test_a_turntable_that_slips_mid_scan_stops_it_and_a_resume_keeps_the_angles(
    tmp_path, capsys, monkeypatch
):
    from scanner.commands.main import main
    from scanner.scan_dir.captures import CaptureStore

    config = _tiny_turntable(tmp_path, driver="tests.turntable_hardware:slipping")
    out = tmp_path / "scan"
    # Follows the check before the scan (its first command), slips on the turn to pass 2.
    monkeypatch.setattr(turntable_hardware, "SLIP_AFTER", 1)
    assert main(["scan", "--config", config, "--out", str(out)]) == 5
    err = _one_line_error(capsys)
    assert "reports 197.19 deg after being told 180.00 deg" in err and "before pass 2" in err
    assert f"scanner scan --resume {out}" in err
    manifest = yaml.safe_load((out / "scan.yaml").read_text())
    assert manifest["status"] == "interrupted" and manifest["turntable_angles_rad"] == [0.0]
    assert CaptureStore.open(out).captured_indices() == list(range(5))  # pass 1 kept
    monkeypatch.setattr(turntable_hardware, "SLIP_AFTER", None)
    assert main(["scan", "--resume", str(out)]) == 0
    manifest = yaml.safe_load((out / "scan.yaml").read_text())
    assert manifest["turntable_angles_rad"] == pytest.approx([0.0, math.pi])
    assert CaptureStore.open(out).captured_indices() == list(range(10))
    report = yaml.safe_load((out / "results" / "report.json").read_text())
    assert [p["angle_deg"] for p in report["presentation"]["passes"]] == pytest.approx([0, 180])


def test_the_next_best_turn_faces_the_cameras_to_the_unseen_side():
    import open3d as o3d

    from reconstruction.evaluation.coverage import SeenSurface
    from reconstruction.evaluation.metrics import SurfaceSamples, TriangleSurface
    from scanner.scan.presentation.next_turn import next_best_turn, wrapped

    centre = np.array([0.4, 0.0, 1.0])
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.08, 20)
    sphere.compute_vertex_normals()
    v = np.asarray(sphere.vertices) + centre
    normals = np.asarray(sphere.vertex_normals)
    surface = TriangleSurface(v, np.asarray(sphere.triangles))
    # The pass's cameras look from below on the -x side; they saw the -x half.
    d = np.array([[-0.7, y, -0.6] for y in (-0.3, 0.0, 0.3)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    seen = SeenSurface(surface, SurfaceSamples(v, normals), normals[:, 0] < 0)
    choice = next_best_turn(seen, centre, 0.5, d)
    # Half a turn brings the unseen +x side to the cameras: far from the pass made (0).
    assert abs(wrapped(choice.turn_rad)) > math.radians(135) and choice.gain > 0.2
    # With that turn made, the next is elsewhere, and gains less.
    other = next_best_turn(seen, centre, 0.5, d, (0.0, choice.turn_rad))
    assert abs(wrapped(other.turn_rad - choice.turn_rad)) >= math.radians(10)
    assert other.gain < choice.gain


def test_the_report_gives_the_calibrated_axis_against_the_model_and_the_truth():
    from reconstruction.hangings.alignment import PassAlignment
    from scanner.scan_dir.known_turns import turntable_report

    turns = KnownTurns((0.0, 2.0), NOMINAL)
    T = turn_about_axis(TRUE_AXIS.p_W, TRUE_AXIS.u_W, -2.0)
    verified = PassAlignment(1, T, 0.8, 3e-4, 0.0, 0.5, 0.0, 1, (), True)
    r = turntable_report(turns, [verified], TRUE_AXIS)
    assert r["axis_calibrated"] and r["known_turn_verified"] == [True]
    assert r["axis_error_mm"] < 1e-6 and r["axis_error_deg"] < 1e-6
    # The true axis is 0.99 mm and 0.1 deg off the model's.
    assert r["axis_offset_mm"] == pytest.approx(0.99, abs=0.01)
    assert r["axis_tilt_deg"] == pytest.approx(math.degrees(0.0017), abs=1e-3)

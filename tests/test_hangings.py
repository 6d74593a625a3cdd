"""Several hangings: the simulator's re-hanging, the alignment of passes and its verification,
free-space consistency, and scans of more than one hanging (resumed between passes)."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from reconstruction.common.transforms import (
    make_pose,
    rotation_about,
    transform_points,
)
from reconstruction.hangings.alignment import AlignmentConfig, align_pass, alignment_error
from reconstruction.hangings.free_space import SeenSpace, free_space_violation
from reconstruction.registration.views import DepthImage
from robots.models.objects import resolve_object
from robots.models.workcell import placed_object
from robots.simulation.operator import hanging_rotation, hung_pose
from tests.conftest import shared_data
from tests.in_process import scanner_in_fixture
from tests.partial_clouds import other_stripes, partial_cloud, stripes
from tests.tiny_scan import TINY_SCAN


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hangings_turn_the_object_by_90_to_180_deg_and_repeat(seed):
    np.testing.assert_array_equal(hanging_rotation(seed, 0), np.eye(3))
    for hanging in (1, 2, 3):
        R = hanging_rotation(seed, hanging)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        tilt = math.degrees(math.acos(np.clip(R[:, 2] @ [0, 0, 1], -1, 1)))
        assert 90 - 1e-9 <= tilt <= 180 + 1e-9
        np.testing.assert_array_equal(R, hanging_rotation(seed, hanging))
    assert not np.allclose(hanging_rotation(seed, 1), hanging_rotation(seed + 10, 1))
    X = hung_pose(make_pose(np.eye(3), [0.4, 0, 1]), seed, 1)
    np.testing.assert_array_equal(X[:3, 3], [0.4, 0, 1])  # turned about its centre


def test_a_rehung_object_hangs_from_its_new_top(tmp_path):
    mesh = resolve_object("bracket", 0.2)
    R = hanging_rotation(0, 1)
    placed = placed_object(tmp_path / "x.obj", mesh.vertices, mesh.triangles, R)
    p_W = R @ np.array(placed.p_OA)
    top = (mesh.vertices @ R.T)[:, 2].max()
    # On the vertical through the centre, at (or just below) the highest point of the object.
    assert np.linalg.norm(p_W[:2]) < 1e-6 or top - p_W[2] < 0.01 * 0.2
    assert p_W[2] > 0 and top - p_W[2] < 0.2


def _plane_view(distance_m: float) -> tuple[DepthImage, np.ndarray]:
    """A camera at the origin looking along +z at a flat wall `distance_m` away."""
    K = np.array([[200.0, 0, 100], [0, 200.0, 100], [0, 0, 1]])
    return DepthImage(np.full((200, 200), distance_m, np.float32), K), np.eye(4)


def test_free_space_counts_points_in_front_of_what_a_view_measured():
    depth, X_WC = _plane_view(1.0)
    seen = SeenSpace((depth,), (X_WC,))
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.3, 0.3, (1000, 2))
    on_wall = np.column_stack([xy, np.full(1000, 1.0)])
    behind = on_wall + [0, 0, 0.2]  # occluded by the wall: proves nothing
    in_front = on_wall - [0, 0, 0.2]  # where the camera saw empty space
    assert free_space_violation(on_wall, seen, 0.003) == 0.0
    assert free_space_violation(behind, seen, 0.003) == 0.0
    assert free_space_violation(in_front, seen, 0.003) == 1.0
    half = np.vstack([on_wall[:500], in_front[500:]])
    assert free_space_violation(half, seen, 0.003) == pytest.approx(0.5)


# The refusals are tested on 0.1 m objects: a refused alignment refines every one of its
# hypotheses, on a quarter of the points of a 0.2 m object's (at the same 3 mm features).


def test_the_texture_must_agree_another_object_of_the_same_shape_is_refused():
    mesh = resolve_object("pebble", 0.1)
    X0 = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    X1 = hung_pose(X0, 3, 1)
    ref, ref_colors = partial_cloud(mesh.vertices, mesh.triangles, X0, 0, stripes)
    same, same_colors = partial_cloud(mesh.vertices, mesh.triangles, X1, 1, stripes)
    a = align_pass(1, same, ref, SeenSpace((), ()), AlignmentConfig(), same_colors, ref_colors)
    assert a.verified, a.failures
    assert a.colour_agreement > 0.5
    other, other_colors = partial_cloud(mesh.vertices, mesh.triangles, X1, 1, other_stripes)
    b = align_pass(1, other, ref, SeenSpace((), ()), AlignmentConfig(), other_colors, ref_colors)
    # Refused. Which check refuses it depends on which hypothesis scores best, and Open3D's
    # multi-threaded RANSAC proposes different ones from run to run: the true pose scores near
    # 0 for its texture, so a wrong pose with a little overlap may win and fail on overlap.
    assert not b.verified, "another object's texture on the same shape was merged"
    # At the true pose the shape fits and the texture does not: that is why it cannot verify.
    from scipy.spatial import cKDTree

    from reconstruction.hangings.alignment import _fit

    config = AlignmentConfig()
    at_truth = _fit(
        transform_points(X0 @ np.linalg.inv(X1), other),
        other_colors.mean(axis=1),
        cKDTree(ref),
        ref_colors.mean(axis=1),
        config.inlier_distance_m,
    )
    assert at_truth.overlap > 0.5
    assert at_truth.colour_agreement < config.min_colour_agreement


def _two_hangings_of(mesh):
    """The mesh hung at X0 and re-hung at X1 as the simulator turns it: each hanging's partial
    cloud (the reference, the moved pass) and the true pass transform T_true."""
    X0 = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    X1 = hung_pose(X0, 3, 1)
    reference = partial_cloud(mesh.vertices, mesh.triangles, X0, 0)
    moved = partial_cloud(mesh.vertices, mesh.triangles, X1, 1)
    return mesh, X0, X1, reference, moved, X0 @ np.linalg.inv(X1)


@pytest.mark.parametrize("name", ["bracket", "pebble"])
def test_two_hangings_of_an_asymmetric_object_align_within_a_fraction_of_a_mm(name):
    # 0.1 m objects, in a third of the time of 0.2 m ones: measured 0.15 mm / 0.04 deg (bracket)
    # and 0.08 mm / 0.07 deg (pebble); at 0.2 m 0.06 and 0.05 mm. Whole scans of 0.2 m objects
    # align within 0.6 mm / 0.3 deg (scripts/bench_complete.py).
    mesh, X0, X1, reference, moved, T_true = _two_hangings_of(resolve_object(name, 0.1))
    a = align_pass(1, moved, reference, SeenSpace((), ()))
    assert a.verified, a.failures
    dt, dr = alignment_error(a.T, T_true, transform_points(X1, mesh.vertices))
    assert dt < 0.5e-3 and math.degrees(dr) < 0.2


def test_hypotheses_that_start_or_end_alike_are_refined_and_scored_once(monkeypatch):
    import reconstruction.hangings.alignment as pa

    mesh, X0, X1, reference, moved, T_true = _two_hangings_of(resolve_object("pebble", 0.2))
    near, apart = T_true.copy(), T_true.copy()
    near[:3, 3] += 0.0005  # starts where the first did
    apart[:3, 3] += 0.004  # starts elsewhere, ends where the first did
    starts = [T_true, T_true.copy(), near, apart]
    monkeypatch.setattr(pa, "feature_hypotheses", lambda *a: [s.copy() for s in starts])
    monkeypatch.setattr(pa, "rotation_grid_hypotheses", lambda *a, **k: [])
    refined, scored = [], []
    refine, violation = pa._refine, pa.free_space_violation
    monkeypatch.setattr(pa, "_refine", lambda *a: refined.append(1) or refine(*a))
    monkeypatch.setattr(pa, "free_space_violation", lambda *a: scored.append(1) or violation(*a))
    a = pa.align_pass(1, moved, reference, SeenSpace((), ()))
    assert len(refined) == 2 and len(scored) == 1
    assert a.hypotheses == 4  # every hypothesis is still counted
    assert a.verified, a.failures
    dt, dr = alignment_error(a.T, T_true, transform_points(X1, mesh.vertices))
    assert dt < 0.5e-3 and math.degrees(dr) < 0.2


def test_ransac_on_features_matched_once_gives_the_libraries_hypotheses():
    import open3d as o3d

    from reconstruction.hangings.alignment import feature_hypotheses, prepared_features

    reg = o3d.pipelines.registration
    mesh = resolve_object("pebble", 0.2)
    X0 = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    X1 = hung_pose(X0, 3, 1)
    config = AlignmentConfig(runs=4, ransac_iterations=2000)
    source, src_f = prepared_features(partial_cloud(mesh.vertices, mesh.triangles, X1, 1), 0.003)
    target, tgt_f = prepared_features(partial_cloud(mesh.vertices, mesh.triangles, X0, 0), 0.003)
    got = feature_hypotheses(source, target, src_f, tgt_f, config)
    distance = 1.5 * config.voxel_m
    for run in range(config.runs):
        # What each run was before: the library matching the features itself.
        o3d.utility.random.seed(1000 + run)
        expected = reg.registration_ransac_based_on_feature_matching(
            source,
            target,
            src_f,
            tgt_f,
            run % 2 == 0,
            distance,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [
                reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                reg.CorrespondenceCheckerBasedOnDistance(distance),
            ],
            reg.RANSACConvergenceCriteria(config.ransac_iterations, 0.9999),
        )
        np.testing.assert_array_equal(got[1 + run], np.asarray(expected.transformation))
    assert len({g.tobytes() for g in got[1:]}) > 1  # the runs differ: the seeds were used


def test_a_symmetric_object_is_refused_as_ambiguous():
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.05, 60)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    X0 = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    X1 = make_pose(rotation_about(np.array([1.0, 0, 0]), 2.0), [0.4, 0.0, 1.0])
    a = align_pass(1, partial_cloud(v, t, X1, 1), partial_cloud(v, t, X0, 0), SeenSpace((), ()))
    assert not a.verified and any("ambiguous" in f for f in a.failures)


def test_a_different_object_is_refused():
    bracket, pebble = resolve_object("bracket", 0.1), resolve_object("pebble", 0.1)
    X = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    a = align_pass(
        1,
        partial_cloud(pebble.vertices, pebble.triangles, X, 1),
        partial_cloud(bracket.vertices, bracket.triangles, X, 0),
        SeenSpace((), ()),
        AlignmentConfig(),
    )
    assert not a.verified


# 10 views per hanging at 640x480 (8 leave no pair of views overlapping for the hand-eye fit;
# at 320x240 the second hanging fails its 1 mm inlier RMS), the tiny scan's roadmap and view
# candidates, Poisson only (depth 7), and a smaller search for the alignment (2 RANSAC runs, 4
# rotation-grid fits kept of each ranking: the same alignment as the whole search, in half its
# time): what these tests check is the alignment, the shared hand-eye fit and the coverage, not
# the finest surface (scripts/bench_complete.py measures the whole search on 1280x960 scans).
SMALL = {
    "camera": {"width_px": 640, "height_px": 480, "focal_px": 660.0},
    "views": {**TINY_SCAN["views"], "count": 10},
    "planner": TINY_SCAN["planner"],
    "processing": {
        "reconstruction": {
            "surfaces": {"methods": ["poisson"], "poisson_depth": 7},
            "alignment": {"runs": 2, "coarse_starts_kept": 4},
        },
        "metric_samples": TINY_SCAN["processing"]["metric_samples"],
    },
}


def _captures(out: Path) -> int:
    folder = out / "captures"
    return len([p for p in folder.iterdir() if p.name.isdigit()]) if folder.is_dir() else 0


@pytest.fixture(scope="module")
def two_hangings(tmp_path_factory):
    """A 2-hanging scan of the Stanford bunny at 640x480 (10 views per hanging), killed with
    SIGKILL in its second hanging, resumed (every check on it checks the resume across
    hangings too) and reconstructed. (A planar part such as the bracket is refused as
    ambiguous at this resolution: its features find no hypothesis that verifies.)"""
    bunny = str(shared_data("meshes/stanford-bunny.obj"))
    tmp = tmp_path_factory.mktemp("scan")
    path = tmp / "small.yaml"
    path.write_text(yaml.safe_dump({**SMALL, "object": bunny, "hangings": 2}))
    out = tmp / "b2"
    cli = [sys.executable, "-m", "scanner", "scan", "--config", str(path), "--out", str(out)]
    proc = subprocess.Popen(cli, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None and _captures(out) < 13:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed = {
        "captures": _captures(out),
        "manifest": yaml.safe_load((out / "scan.yaml").read_text()),
    }
    # The resume in this process: what is checked is the resume, not a process (the kill is).
    r = scanner_in_fixture("scan", "--resume", out)
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "results" / "report.json").read_text())
    return SimpleNamespace(scan_dir=out, report=report, killed=killed)


@pytest.mark.slow
def test_a_two_hanging_scan_is_aligned_and_sees_the_whole_object(two_hangings):
    r = two_hangings.report
    assert r["views_captured"] == 20 and r["status"] == "complete"
    passes = r["hangings"]
    assert [p["views"] for p in passes] == [10, 10]
    assert passes[1]["verified"] is True
    # At 640x480 the stereo noise is about twice the product's (1280x960; the 0.5 mm /
    # 0.2 deg targets are measured there by scripts/bench_complete.py).
    assert r["alignment_error_mm"] < 1.0 and r["alignment_error_deg"] < 0.5
    # One X_FC shared by both hangings, corrected and diagnosed as in a single-hanging scan.
    assert r["handeye_converged"] is True and r["handeye_diagnosis"]["failures"] == []
    assert r["handeye_error_mm"] < 1.0 and r["handeye_error_deg"] < 0.2
    # Both hangings together see (nearly) all of the object; one alone sees about 70 %.
    assert r["observed_fraction"] > 0.95 and r["completeness_2mm"] > 0.9
    assert abs(r["coverage_estimate"] - r["observed_fraction"]) < 0.05
    # The hangings together surround the object: its closed model is watertight and bridges
    # little beyond the data: at most about 3 % of the bunny's 0.094 m^2. Measured with 12
    # views a hanging and Poisson depth 8: 0.0015 m^2 with one stereo pass; 0.0019 (straight
    # through) to 0.0024 m^2 (killed and resumed) with the upward pass, which drops the pixels
    # where its two passes disagree, so more of the grazing rim is bridged. With these 10 views
    # and depth 7: 0.0022 (straight through) and 0.0023 m^2 (this scan).
    assert r["closed_model"]["watertight"] and r["closed_model"]["filled_area_m2"] < 0.003
    # That bridged area is the closed model's interpolated share (the bunny: 0.094 m^2).
    assert 0 < r["closed_model"]["interpolated_fraction"] < 0.003 / 0.09
    summary = (two_hangings.scan_dir / "results" / "summary.md").read_text()
    assert "% of its area is interpolated, not measured" in summary
    # All of the bunny is observable from somewhere around it; the two hangings saw nearly all.
    assert r["observable_fraction"] > 0.999 and r["completeness_observable_2mm"] > 0.9
    for p in passes:  # each hanging alone saw less than both together
        assert 0 <= p["coverage_estimate"] <= 1
        assert p["observed_fraction"] < r["observed_fraction"]
    truth = yaml.safe_load((two_hangings.scan_dir / "truth.yaml").read_text())
    assert len(truth["X_WO_hangings"]) == 2
    manifest = yaml.safe_load((two_hangings.scan_dir / "scan.yaml").read_text())
    assert manifest["hanging"] == 1 and len(manifest["hangings"]) == 2


@pytest.mark.slow
def test_no_rod_of_either_hanging_is_in_the_model(two_hangings):
    """Each hanging's rod, removed in that hanging's own frame, is in none of the merged
    model's points: the fused cloud and every mesh, checked against the true rod lines (the
    guard on flat and elongated shapes: test_fixture_removal.py; over the benchmark objects:
    bench_complete's fixture_points_max)."""
    import open3d as o3d

    from tests.rods import rod_points

    scan = two_hangings.scan_dir
    results = scan / "results"
    assert two_hangings.report["fixture_points"] == 0  # the report's own count agrees
    hung = yaml.safe_load((scan / "truth.yaml").read_text())["X_WO_hangings"]
    true_vertices = np.asarray(o3d.io.read_triangle_mesh(str(scan / "truth_mesh.ply")).vertices)
    fused = np.asarray(o3d.io.read_point_cloud(str(results / "fused_cloud.ply")).points)
    assert len(fused) > 10_000 and rod_points(fused, true_vertices, hung) == 0
    meshes = sorted(results.glob("mesh_*.ply"))
    assert {m.name for m in meshes} >= {"mesh_poisson.ply", "mesh_poisson_closed.ply"}
    for mesh in meshes:
        vertices = np.asarray(o3d.io.read_triangle_mesh(str(mesh)).vertices)
        assert len(vertices) > 1000, mesh.name
        assert rod_points(vertices, true_vertices, hung) == 0, mesh.name


@pytest.mark.slow
def test_merging_scans_of_different_objects_is_refused(tmp_path, capsys):
    from scanner.commands.main import main
    from scanner.configs.scan import load_scan_config
    from scanner.scan.run import run_scan

    # Tiny scans of 0.1 m objects: the refused alignment tries every hypothesis, on a quarter
    # of the points of 0.2 m objects; it fails its texture, free-space and RMS checks alike.
    tiny = {**TINY_SCAN, "reconstruct": False, "cell": {"object_size_m": 0.1}}
    scans = []
    for name in ("pebble", "bracket"):
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump({**tiny, "object": name}))
        scans.append(run_scan(load_scan_config(path), tmp_path / name).scan_dir)
    out = tmp_path / "merged"
    capsys.readouterr()
    assert main(["merge", *map(str, scans), "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert "could not be aligned" in err and "no model written" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_merge_refuses_bad_input(two_hangings, tmp_path):
    import shutil

    from reconstruction.common.errors import ScannerError
    from scanner.reconstruct.merge import run_merge

    scan = two_hangings.scan_dir
    with pytest.raises(ScannerError, match="two or more scan directories"):
        run_merge([scan], tmp_path / "a")
    with pytest.raises(ScannerError, match="more than once"):
        run_merge([scan, scan], tmp_path / "b")
    (tmp_path / "notes").mkdir()
    with pytest.raises(ScannerError, match="not a scan directory"):
        run_merge([scan, tmp_path / "notes"], tmp_path / "c")
    other = tmp_path / "other-camera"
    shutil.copytree(scan, other, ignore=shutil.ignore_patterns("captures", "results"))
    manifest = yaml.safe_load((other / "scan.yaml").read_text())
    manifest["camera"]["left"]["K"][0][0] *= 1.1
    (other / "scan.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    with pytest.raises(ScannerError, match="another camera model"):
        run_merge([scan, other], tmp_path / "d")
    assert not any((tmp_path / n).exists() for n in "abcd")


@pytest.mark.slow
def test_a_scan_killed_in_its_second_hanging_resumes_there(two_hangings):
    from scanner.scan_dir.captures import CaptureStore

    killed = two_hangings.killed
    assert 10 < killed["captures"] < 20, "killed in the second hanging"
    assert killed["manifest"]["hanging"] == 1 and killed["manifest"]["status"] == "running"
    assert CaptureStore.open(two_hangings.scan_dir).captured_indices() == list(range(20))
    # The views captured after the resume saw the object in its second hanging: the second
    # pass aligns with the first (test_a_two_hanging_scan_is_aligned... checks how well).
    assert two_hangings.report["hangings"][1]["verified"]


def test_an_earlier_alignment_is_refined_without_a_search_and_a_wrong_one_is_searched_anew(
    monkeypatch,
):
    """The quick model's verified alignment of the same captures (here: the truth a millimetre
    and a half degree off, as the mount's correction moves it) is refined and verified with
    no hypothesis searched; one that no longer fits (turned by 90 deg) leads to the search."""
    import reconstruction.hangings.alignment as pa

    mesh, X0, X1, reference, moved, T_true = _two_hangings_of(resolve_object("pebble", 0.1))
    points_1 = transform_points(X1, mesh.vertices)
    searched = []
    search = pa.feature_hypotheses
    monkeypatch.setattr(pa, "feature_hypotheses", lambda *a: searched.append(1) or search(*a))

    centre = X0[:3, 3]  # where the object is, in the reference frame

    def about_centre(R: np.ndarray, t=(0.0, 0.0, 0.0)) -> np.ndarray:
        return make_pose(R, centre + np.asarray(t) - R @ centre)

    off = about_centre(rotation_about(np.array([0.0, 1.0, 0.0]), math.radians(0.5)), [1e-3, 0, 0])
    earlier = pa.PassAlignment(1, off @ T_true, *[math.nan] * 4, 0.3, 40, ())
    a = pa.align_pass(1, moved, reference, SeenSpace((), ()), earlier=earlier)
    assert a.verified and a.from_earlier and not searched
    assert a.ambiguity == 0.3 and a.hypotheses == 1  # the search that found it measured that
    dt, dr = alignment_error(a.T, T_true, points_1)
    assert dt < 0.5e-3 and math.degrees(dr) < 0.2

    wrong = about_centre(rotation_about(np.array([0.0, 0.0, 1.0]), math.pi / 2)) @ T_true
    b = pa.align_pass(1, moved, reference, SeenSpace((), ()), earlier=replace(earlier, T=wrong))
    assert searched and not b.from_earlier and b.hypotheses > 1
    assert b.verified, b.failures
    dt, dr = alignment_error(b.T, T_true, points_1)
    assert dt < 0.5e-3 and math.degrees(dr) < 0.2

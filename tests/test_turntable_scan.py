"""A scan of the bunny on the turntable: three passes at the small settings of the hanging tests
(6 views each at 640x480), turned by 180 deg, then laid on another face onto the disc; the
known turn starts the second pass's alignment, which verifies it, the laid pass aligns by the
search, the angles and the laid face are recorded with the passes, and no point of the support
reaches the fused cloud."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from tests.conftest import shared_data
from tests.test_hangings import SMALL

# Six views a pass and an exact mount, so the nominal one is kept (the shared hand-eye fit is the
# two-hanging test's):
# what this checks is that the known turn starts and verifies the pass alignment, and what is
# recorded; bench_presentation measures whole turntable scans at the product's settings.
TURNTABLE = {
    **SMALL,
    "views": {**SMALL["views"], "count": 6},
    "error_model": {"handeye_translation_m": 0.0, "handeye_rotation_rad": 0.0},
    "processing": {
        **SMALL["processing"],
        "reconstruction": {
            **SMALL["processing"]["reconstruction"],
            "surfaces": {"methods": ["poisson"], "poisson_depth": 6},
            "handeye": {"enabled": False},
        },
    },
}


@pytest.fixture(scope="module")
def turntable_scan(tmp_path_factory):
    from scanner.configs.scan import load_scan_config
    from scanner.scan.run import run_scan

    bunny = str(shared_data("meshes/stanford-bunny.obj"))
    tmp = tmp_path_factory.mktemp("turntable")
    path = tmp / "small.yaml"
    config = {**TURNTABLE, "object": bunny, "hangings": 3, "presentation": "turntable"}
    path.write_text(yaml.safe_dump(config))
    return run_scan(load_scan_config(path), tmp / "bunny").scan_dir


@pytest.mark.slow
def test_a_turntable_scan_aligns_by_its_known_turn_then_ends_laid_anew(turntable_scan):
    from robots.models.objects import resolve_object
    from robots.models.table import nearest_pose
    from robots.simulation.laying import stable_poses
    from robots.simulation.truth import hung_pose_of

    r = json.loads((turntable_scan / "results" / "report.json").read_text())
    assert r["status"] == "complete" and r["views_captured"] == 18
    second, third = r["hangings"][1], r["hangings"][2]
    assert second["verified"] and second["known_turn_verified"]
    # Laid anew, no turn is known: the search aligns it, as a hanging.
    assert third["verified"] and not third.get("known_turn_verified", False)
    # The two-hanging test's bounds, but for the turn: seen from the robot's side from above,
    # two passes 180 deg apart overlap on the object's top alone, along which the fit slides,
    # keeping the nominal axis (0.9 mm off the true one): measured 1.10 mm / 0.13 deg.
    assert second["alignment_error_mm"] < 1.5 and second["alignment_error_deg"] < 0.5
    assert third["alignment_error_mm"] < 1.0 and third["alignment_error_deg"] < 0.5
    turntable = r["turntable"]
    assert turntable["angles_deg"] == pytest.approx([0.0, 180.0, 180.0])
    assert turntable["axis_offset_mm"] < 2.0
    passes = r["presentation"]["passes"]
    assert [p["angle_deg"] for p in passes] == pytest.approx([0.0, 180.0, 180.0])
    assert "turned evenly around" in passes[1]["why"] and passes[1]["turn_deg"] == 180.0
    assert "laid_on" in passes[2] and "turn_deg" not in passes[2]
    assert "laid anew" in passes[2]["why"]
    manifest = yaml.safe_load((turntable_scan / "scan.yaml").read_text())
    assert manifest["turntable_angles_rad"] == pytest.approx([0.0, math.pi, math.pi])
    assert list(manifest["turntable_laid_passes"]) == ["2"]
    # The simulated person laid it so: of the bunny's stable faces, the one nearest the side
    # that faced the robot lies underneath.
    X1, X2 = (hung_pose_of(turntable_scan / "truth.yaml", p) for p in (1, 2))
    poses, _ = stable_poses(resolve_object(str(shared_data("meshes/stanford-bunny.obj")), 0.2))
    face = nearest_pose(poses, X1[:3, :3].T @ [-1.0, 0.0, 0.0])
    assert (X2[:3, :3] @ face.down_O) @ [0.0, 0.0, -1.0] > math.cos(math.radians(1.0))
    # Laid anew, it shows what it stood on: more than the turns alone.
    assert r["observed_fraction"] > max(p["observed_fraction"] for p in r["hangings"][:2]) + 0.05
    summary = (turntable_scan / "results" / "summary.md").read_text()
    assert "turntable" in summary and "180" in summary


@pytest.mark.slow
def test_no_point_of_the_support_reaches_the_fused_cloud(turntable_scan):
    from reconstruction.common.mesh_files import read_triangle_mesh
    from reconstruction.evaluation.metrics import TriangleSurface, distances_to_mesh

    fused = np.asarray(
        __import__("open3d")
        .io.read_point_cloud(str(turntable_scan / "results" / "fused_cloud.ply"))
        .points
    )
    mesh = read_triangle_mesh(turntable_scan / "truth_mesh.ply")
    truth = TriangleSurface(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    d = distances_to_mesh(fused, truth)
    # Every pass's points in the first pass's frame: the disc, post and cell table of each
    # (a laid pass's, turned over, would lie above the object) would be centimetres off, a
    # few per cent of the cloud (the fandisk on the table, before the cut: 2.3 %); what stays
    # is the stereo's stray matches (a 5-view scan like this one: 0.16 %).
    assert (d > 0.01).mean() < 0.005

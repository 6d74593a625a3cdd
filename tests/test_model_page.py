"""model.html without a browser: the page's scene commands decoded from the file (Meshcat embeds
each as base64 msgpack), its layers, colours and size; `scanner view`'s choice of page and its
refusals."""

from __future__ import annotations

import base64
import logging
import re
import shutil
from pathlib import Path

import msgpack
import numpy as np
import pytest

from reconstruction.stereo.camera_model import PinholeCamera
from scanner.reports.deviation_picture import colour_map_rgb
from scanner.reports.model_page import (
    CELL_PATH,
    FIXTURE_PATH,
    MODEL_PATH,
    PAGE_NAME,
    ROBOT_PATH,
    UNSEEN_PATH,
    VIEWS_PATH,
    mesh_colours,
    write_model_page,
)
from scanner.reports.model_page_layers import (
    DisplayMesh,
    ModelScene,
    RobotPose,
    ViewFrustum,
    box_segments,
    frustum_segments,
)

MAX_PAGE_BYTES = 15e6  # the default scan's page must stay below this


def page_commands(path: Path) -> list[dict]:
    """Every scene command embedded in a Meshcat static page, decoded."""
    blobs = re.findall(
        r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"', path.read_text()
    )
    return [msgpack.unpackb(base64.b64decode(b), strict_map_key=False) for b in blobs]


def object_paths(commands: list[dict]) -> set[str]:
    return {c["path"] for c in commands if c["type"] == "set_object"}


def mesh_colour_array(commands: list[dict], path: str) -> np.ndarray:
    """The per-vertex colours (V, 3) of the triangle mesh set at `path`."""
    (command,) = [c for c in commands if c["type"] == "set_object" and c["path"] == path]
    attributes = command["object"]["geometries"][0]["data"]["attributes"]
    return np.frombuffer(attributes["color"]["array"].data, np.float32).reshape(-1, 3)


def _camera() -> PinholeCamera:
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    return PinholeCamera(K, np.zeros(5), 320, 240)


def _sphere_scene(values_m: np.ndarray | None = None) -> ModelScene:
    import open3d as o3d

    from robots.models.workcell import WorkcellConfig

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.08, resolution=20)
    v = np.asarray(sphere.vertices) + [0.4, 0.0, 1.0]
    t = np.asarray(sphere.triangles)
    values = np.linspace(-0.002, 0.002, len(v)) if values_m is None else values_m
    X_WC = np.eye(4)
    X_WC[:3, 3] = [0.4, 0.0, 0.5]  # below the object, looking up (+z)
    frustums = (ViewFrustum(X_WC, 0), ViewFrustum(X_WC @ np.diag([1, -1, -1, 1.0]), 0))
    frustums += (ViewFrustum(X_WC, 1),)
    return ModelScene(
        mesh=DisplayMesh(v, t, values),
        scale_m=0.001,
        colour_meaning="test sphere: signed deviation",
        unseen_W=v[:50] * 1.01,
        frustums=frustums,
        camera=_camera(),
        fixture_segments=((np.array([0.4, 0.0, 1.0]), np.array([0.4, 0.0, 1.8])),),
        cell=WorkcellConfig(),
        robot=RobotPose(np.zeros(6), np.eye(4), np.eye(4)),
    )


def test_the_page_holds_every_layer_and_one_frustum_per_view(tmp_path):
    scene = _sphere_scene()
    page = write_model_page(scene, tmp_path / PAGE_NAME)
    assert page.size_bytes == (tmp_path / PAGE_NAME).stat().st_size < MAX_PAGE_BYTES
    paths = object_paths(page_commands(page.path))
    assert f"{MODEL_PATH}/mesh" in paths
    assert f"{UNSEEN_PATH}/points" in paths
    assert f"{FIXTURE_PATH}/axes" in paths
    assert {f"{CELL_PATH}/{b.name}" for b in scene.cell.boxes} <= paths
    assert any(p.startswith(f"{ROBOT_PATH}/rx60/") for p in paths)
    frustums = sorted(p for p in paths if p.startswith(VIEWS_PATH))
    assert len(frustums) == len(scene.frustums)
    assert sum(p.startswith(f"{VIEWS_PATH}/hanging_2/") for p in frustums) == 1
    assert set(page.layers) >= {MODEL_PATH, UNSEEN_PATH, VIEWS_PATH, CELL_PATH, ROBOT_PATH}


def test_colours_follow_the_deviation_pictures_scale(tmp_path):
    """A vertex on the reference is the map's middle colour, one at +-scale (or beyond) its
    ends: the page and the PNG pictures read alike."""
    scene = _sphere_scene()
    n = len(scene.mesh.vertices_W)
    values = np.zeros(n)
    values[0], values[1], values[2] = 0.001, -0.001, 0.05
    scene = _sphere_scene(values)
    rgb = colour_map_rgb() / 255.0
    colours = mesh_colours(scene.mesh, scene.scale_m)
    np.testing.assert_allclose(colours[0], rgb[-1], atol=1e-9)
    np.testing.assert_allclose(colours[1], rgb[0], atol=1e-9)
    np.testing.assert_allclose(colours[2], rgb[-1], atol=1e-9)  # saturates beyond the scale
    np.testing.assert_allclose(colours[3], rgb[len(rgb) // 2], atol=2.5e-3)
    page = write_model_page(scene, tmp_path / PAGE_NAME)
    in_page = mesh_colour_array(page_commands(page.path), f"{MODEL_PATH}/mesh")
    np.testing.assert_allclose(in_page, colours, atol=1e-6)  # float32 in the page


def test_frustum_and_box_geometry():
    X_WC = np.eye(4)
    X_WC[:3, 3] = [1.0, 2.0, 3.0]
    start, end = frustum_segments(X_WC, _camera(), depth_m=0.05)
    assert start.shape == end.shape == (8, 3)
    np.testing.assert_allclose(start[:4], [[1.0, 2.0, 3.0]] * 4)
    np.testing.assert_allclose(end[:4, 2], 3.05)  # the image plane at the depth, along +z
    np.testing.assert_allclose(end[0, :2], [1.0 - 160 / 300 * 0.05, 2.0 - 120 / 300 * 0.05])
    s, e = box_segments(np.zeros(3), np.array([2.0, 4.0, 6.0]))
    lengths = np.sort(np.linalg.norm(e - s, axis=1))
    np.testing.assert_allclose(lengths, [2.0] * 4 + [4.0] * 4 + [6.0] * 4)


def test_a_page_beside_a_live_viewer_takes_another_port(tmp_path):
    from pydrake.geometry import Meshcat

    live = Meshcat()
    page = write_model_page(_sphere_scene(), tmp_path / PAGE_NAME)
    assert page.path.is_file()
    assert live.port() > 0  # the live viewer keeps serving on its port


def test_a_page_that_fails_costs_a_warning_not_the_results(tmp_path, caplog):
    from scanner.reconstruct.model_scene import write_reconstruction_page

    def broken():
        raise RuntimeError("no meshcat here")

    with caplog.at_level(logging.WARNING, logger="scanner.reconstruct.model_scene"):
        assert write_reconstruction_page(tmp_path, broken) is None
    assert "model.html not written" in caplog.text and "no meshcat here" in caplog.text
    assert not (tmp_path / PAGE_NAME).exists()


def test_the_scans_results_have_the_page(tiny_scan):
    """The tiny scan's results: model.html beside summary.md, linked from it, one frustum per
    view used, the deviation from the truth as colours."""
    results = tiny_scan.scan_dir / "results"
    page = results / PAGE_NAME
    assert page.is_file() and page.stat().st_size < MAX_PAGE_BYTES
    assert f"]({PAGE_NAME})" in (results / "summary.md").read_text()
    assert tiny_scan.report["model_page"] == PAGE_NAME
    commands = page_commands(page)
    paths = object_paths(commands)
    frustums = [p for p in paths if p.startswith(f"{VIEWS_PATH}/")]
    assert len(frustums) == tiny_scan.report["captures_used"]
    assert {f"{MODEL_PATH}/mesh", f"{UNSEEN_PATH}/points", f"{FIXTURE_PATH}/axes"} <= paths
    assert any(p.startswith(f"{ROBOT_PATH}/") for p in paths)
    colours = mesh_colour_array(commands, f"{MODEL_PATH}/mesh")
    rgb = colour_map_rgb() / 255.0
    nearest = np.min(np.linalg.norm(colours[:, None, :] - rgb[None, :, :], axis=2), axis=1)
    assert nearest.max() < 1e-3  # every vertex wears a colour of the map


def test_scan_and_reconstruct_print_where_the_page_is(tiny_scan):
    from scanner.commands.scan import scan_result_lines

    page = tiny_scan.scan_dir / "results" / PAGE_NAME
    assert f"3D page: {page} (scanner view {tiny_scan.scan_dir})" in scan_result_lines(tiny_scan)


def _run_view(args: list[str], capsys) -> tuple[int, str, str]:
    from scanner.commands.main import main

    code = main(["view", "--no-browser", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_view_finds_the_newest_page_of_a_scan(tiny_scan, tmp_path, capsys):
    scan = tmp_path / "scan"
    shutil.copytree(tiny_scan.scan_dir, scan, ignore=shutil.ignore_patterns("captures"))
    code, out, _ = _run_view([str(scan)], capsys)
    assert code == 0 and out.strip().endswith(str((scan / "results" / PAGE_NAME).resolve()))
    shutil.copytree(scan / "results", scan / "results-3")
    code, out, _ = _run_view([str(scan)], capsys)
    assert code == 0 and "results-3" in out
    code, out, _ = _run_view([str(scan / "results")], capsys)
    assert code == 0 and out.strip().endswith(str((scan / "results" / PAGE_NAME).resolve()))


def test_view_refuses_what_has_no_page(tiny_scan, tmp_path, capsys):
    old = tmp_path / "scan"
    shutil.copytree(tiny_scan.scan_dir, old, ignore=shutil.ignore_patterns("captures"))
    (old / "results" / PAGE_NAME).unlink()
    code, _, err = _run_view([str(old / "results")], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "has no model.html" in err and f"scanner reconstruct {old}" in err
    code, _, err = _run_view([str(tmp_path)], capsys)
    assert code == 2 and "not a scan directory" in err
    empty = tmp_path / "captured-only"
    empty.mkdir()
    (empty / "scan.yaml").write_text("{}\n")
    code, _, err = _run_view([str(empty)], capsys)
    assert code == 2 and f"make one with: scanner reconstruct {empty}" in err


@pytest.mark.parametrize("names", [["results", "results-2", "results-10", "results-x"]])
def test_latest_results_folder(tmp_path, names):
    from scanner.scan_dir.results_folder import latest_results_dir

    for name in names:
        (tmp_path / name).mkdir()
        (tmp_path / name / "marker").touch()
    (tmp_path / "results-11").mkdir()  # unfinished: no marker
    assert latest_results_dir(tmp_path, "marker") == tmp_path / "results-10"
    assert latest_results_dir(tmp_path / "results-11", "marker") is None


def test_without_truth_the_colours_are_the_distance_to_the_data():
    """A vertex on the fused cloud is white, one at the coverage estimate's support distance
    (or beyond: no data held it) the map's red end."""
    from types import SimpleNamespace

    from reconstruction.evaluation.coverage import SUPPORT_M
    from scanner.configs.scan import ProcessingConfig
    from scanner.reconstruct.model_scene import colouring

    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    result = SimpleNamespace(fused=SimpleNamespace(points_W=points))
    vertices = np.array([[0.0, 0.0, SUPPORT_M], [1.0, 0.0, 0.0], [0.0, 0.0, -0.01]])
    c = colouring(vertices, result, None, ProcessingConfig())
    np.testing.assert_allclose(c.values_m, [SUPPORT_M, 0.0, 0.01], atol=1e-12)
    assert not c.signed and c.scale_m == SUPPORT_M and "measured" in c.meaning
    colours = mesh_colours(DisplayMesh(vertices, np.array([[0, 1, 2]]), c.values_m), c.scale_m)
    rgb = colour_map_rgb() / 255.0
    np.testing.assert_allclose(colours[[0, 2]], rgb[[-1, -1]])
    np.testing.assert_allclose(colours[1], rgb[len(rgb) // 2], atol=2.5e-3)


def test_only_what_is_displayed_is_decimated():
    import open3d as o3d

    from scanner.reports.model_page_layers import decimated, thinned

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.1, resolution=60)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    small_v, small_t = decimated(v, t, max_triangles=2_000)
    assert len(small_t) <= 2_000 and len(small_v) < len(v)
    radii = np.linalg.norm(small_v, axis=1)
    assert np.abs(radii - 0.1).max() < 0.005  # still the sphere
    same_v, same_t = decimated(v, t, max_triangles=len(t))
    np.testing.assert_array_equal(same_v, v)
    np.testing.assert_array_equal(same_t, t)
    assert len(thinned(np.zeros((50, 3)), 10)) == 10 and len(thinned(np.zeros((5, 3)), 10)) == 5


def test_view_opens_a_browser_in_a_graphical_session(tiny_scan, monkeypatch, capsys):
    import webbrowser

    opened = []

    class Browser:  # the platform's own call, which says whether it worked
        def open(self, url):
            opened.append(url)
            return True

    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(webbrowser, "get", Browser)
    from scanner.commands.main import main

    assert main(["view", str(tiny_scan.scan_dir)]) == 0
    page = (tiny_scan.scan_dir / "results" / PAGE_NAME).resolve()
    assert opened == [page.as_uri()]
    assert capsys.readouterr().out.strip() == f"opened: {page}"
    monkeypatch.delenv("DISPLAY")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(tiny_scan.scan_dir)]) == 0
    assert len(opened) == 1 and capsys.readouterr().out.startswith("model page: ")


def test_an_inspection_writes_its_page(tiny_scan, tmp_path):
    from scanner.inspect.inspection import InspectOptions, run_inspect
    from scanner.reports.model_page import REFERENCE_PATH

    options = InspectOptions(
        reference=tiny_scan.scan_dir / "truth_mesh.ply", align="none", out=tmp_path / "inspection"
    )
    run = run_inspect(tiny_scan.scan_dir, options)
    page = run.out / PAGE_NAME
    assert "model.html" in run.report["files"] and page.stat().st_size < MAX_PAGE_BYTES
    assert "](model.html)" in (run.out / "summary.md").read_text()
    paths = object_paths(page_commands(page))
    assert {f"{MODEL_PATH}/mesh", f"{REFERENCE_PATH}/mesh"} <= paths

"""End-to-end simulated scans: tiny (few views, low resolution), killed and resumed, bad input.
The command line runs in this process (tests.in_process) except where a process is killed or
signalled."""

import json
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from scanner.configs.scan import ScanConfig, load_scan_config
from scanner.scan.run import run_scan
from scanner.scan_dir.captures import CaptureStore
from tests.in_process import scanner
from tests.scan_copies import interrupted_copy
from tests.tiny_scan import TINY_SCAN


@pytest.fixture(scope="module")
def tiny_config_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY_SCAN))
    return path


def test_tiny_scan_captures_every_view(tiny_scan):
    r = tiny_scan.report
    assert r["views_planned"] == 5 and r["views_captured"] == 5 and r["views_skipped"] == 0
    assert r["status"] == "complete"  # captured, then reconstructed
    assert r["robot_motion_s"] > 0
    for key in ("setup", "viewpoints", "ordering", "capture"):
        assert r["stage_s"][key] >= 0
    store = CaptureStore.open(tiny_scan.scan_dir)
    assert store.captured_indices() == [0, 1, 2, 3, 4]
    manifest = store.read_manifest()
    assert manifest["status"] == "complete" and manifest["pose_count"] == 5
    # The end-to-end run reconstructs too (at 320x240 a coarse model; the accuracy of the
    # reconstruction is tested at full resolution in test_reconstruct_scan.py).
    assert 0 < r["accuracy_p90_mm"] < 10 and r["completeness_observed_2mm"] > 0.3
    assert (tiny_scan.scan_dir / "results" / "mesh_poisson.ply").is_file()
    assert (tiny_scan.scan_dir / "truth.yaml").is_file()
    assert (tiny_scan.scan_dir / "truth_mesh.ply").is_file()


def test_the_scan_prints_its_figures_with_verdicts_and_where_the_summary_is(tiny_scan):
    from scanner.commands.scan import scan_result_lines
    from scanner.reports.judgement import FIGURES

    lines = scan_result_lines(tiny_scan)
    r = tiny_scan.report
    summary = tiny_scan.scan_dir / "results" / "summary.md"
    assert f"summary: {summary}" in lines and summary.is_file()
    (figures,) = [line for line in lines if line.startswith("poisson: ")]
    verdict = FIGURES["chamfer_observed_mm"].verdict(r["chamfer_observed_mm"])
    assert f"Chamfer {r['chamfer_observed_mm']:.3f} mm observed ({verdict})" in figures


def test_captures_record_the_pose_they_were_taken_at(tiny_scan):
    from robots.models.kinematics import Kinematics

    store = CaptureStore.open(tiny_scan.scan_dir)
    kin = Kinematics()
    centre = np.array(ScanConfig().scan_center_m)
    for i in store.captured_indices():
        c = store.read_capture(i)
        np.testing.assert_allclose(c.X_WF, kin.X_WF(c.q_rad), atol=1e-12)
        assert c.left.shape == (240, 320, 3)
        # The flange looks at the object: the centre is in front of the camera.
        X_WF = c.X_WF
        assert (centre - X_WF[:3, 3]) @ X_WF[:3, 2] > 0.3
        assert c.left.std() > 10  # not a blank frame


def _captures(scan_dir: Path) -> list[int]:
    d = scan_dir / "captures"
    return sorted(int(p.name) for p in d.iterdir() if p.name.isdigit()) if d.exists() else []


def _scanner(*args, env=None):
    return [sys.executable, "-m", "scanner", "scan", *args]


def _start_six_view_scan(tiny_config_file, out: Path, output) -> subprocess.Popen:
    """A 6-view capture-only scan in a child process (these tests are about the captures)."""
    cfg = yaml.safe_load(tiny_config_file.read_text())
    cfg["views"]["count"] = 6
    cfg["reconstruct"] = False
    config_file = out.parent / "six.yaml"
    config_file.write_text(yaml.safe_dump(cfg))
    args = _scanner("--config", str(config_file), "--out", str(out))
    return subprocess.Popen(args, stdout=output, stderr=output, text=True)


def _wait_for_captures(proc: subprocess.Popen, out: Path, k: int) -> None:
    deadline = time.monotonic() + 240
    while len(_captures(out)) < k and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)


def test_killed_scan_resumes_without_duplicates(tiny_config_file, tmp_path, tiny_scan, capfd):
    out = tmp_path / "killed"
    proc = _start_six_view_scan(tiny_config_file, out, subprocess.DEVNULL)
    _wait_for_captures(proc, out, 2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    k = len(_captures(out))
    assert 2 <= k < 6, f"the scan should have been killed mid-way, it had {k} captures"
    before = {i: (out / "captures" / f"{i:04d}" / "left.png").read_bytes() for i in _captures(out)}
    r = scanner(capfd, "scan", "--resume", out)
    assert r.returncode == 0, r.stderr
    store = CaptureStore.open(out)
    assert store.captured_indices() == list(range(6))
    assert not list((out / "captures").glob(".tmp-*"))
    for i in range(6):
        store.read_capture(i)  # every capture complete and readable
    for i, data in before.items():  # nothing captured before the kill was rewritten
        assert (out / "captures" / f"{i:04d}" / "left.png").read_bytes() == data
    # Every view captured, reconstruction not configured: a further resume changes nothing.
    assert store.read_manifest()["status"] == "captured"
    manifest = store.manifest_path.read_bytes()
    r = scanner(capfd, "scan", "--resume", out)
    assert r.returncode == 2 and "nothing was changed" in r.stderr, r.stderr
    assert store.manifest_path.read_bytes() == manifest


def test_sigterm_finishes_the_current_capture_and_leaves_a_resumable_scan(
    tiny_config_file, tmp_path
):
    out = tmp_path / "stopped"
    proc = _start_six_view_scan(tiny_config_file, out, subprocess.PIPE)
    _wait_for_captures(proc, out, 1)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert f"--resume {out}" in stdout
    store = CaptureStore.open(out)
    assert store.read_manifest()["status"] == "interrupted"
    k = len(store.captured_indices())
    assert 1 <= k < 6
    assert not list((out / "captures").glob(".tmp-*"))
    for i in store.captured_indices():
        store.read_capture(i)
    assert "aborted" in (out / "scan.log").read_text().lower()


def test_offline_reconstruct_never_replaces_an_earlier_reconstruction(tiny_scan, tmp_path, capfd):
    scan_dir = tmp_path / "scan"
    shutil.copytree(tiny_scan.scan_dir, scan_dir)
    first = (scan_dir / "results" / "mesh_poisson.ply").read_bytes()
    cli = ["reconstruct", scan_dir, "--no-icp"]
    r = scanner(capfd, *cli)
    assert r.returncode == 0, r.stderr
    second = scan_dir / "results-2"
    assert f"results: {second}" in r.stdout
    assert (scan_dir / "results" / "mesh_poisson.ply").read_bytes() == first
    report = json.loads((second / "report.json").read_text())
    assert report["captures_used"] == 5 and report["chamfer_mm"] > 0
    # An explicit --out that holds a reconstruction is refused unless --force; one inside the
    # scan it reads is refused in any case.
    elsewhere = tmp_path / "elsewhere"
    shutil.copytree(second, elsewhere)
    r = scanner(capfd, *cli, "--out", elsewhere)
    assert r.returncode == 2 and "holds a reconstruction already" in r.stderr, r.stderr
    r = scanner(capfd, *cli, "--out", second)
    assert r.returncode == 2 and "is inside SCAN_DIR" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert json.loads((second / "report.json").read_text()) == report
    assert json.loads((elsewhere / "report.json").read_text()) == report


def test_a_scan_runs_on_a_hardware_driver(tiny_config_file, tmp_path):
    config = load_scan_config(tiny_config_file)
    config = replace(config, driver="tests.simulated_hardware:connect")
    config = replace(config, views=replace(config.views, count=3))
    result = run_scan(config, tmp_path / "hw")
    r = result.report
    assert r["status"] == "complete" and r["views_captured"] == 3
    # Hardware knows no truth: nothing is written that only the simulator could know, and the
    # reconstruction still runs (without metrics).
    assert not (result.scan_dir / "truth.yaml").exists()
    assert "chamfer_mm" not in r
    assert (result.scan_dir / "results" / "mesh_poisson.ply").stat().st_size > 0
    manifest = CaptureStore.open(result.scan_dir).read_manifest()
    assert manifest["config"]["driver"] == "tests.simulated_hardware:connect"


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--driver", "no_such_module:connect"], "cannot import 'no_such_module'"),
        (["--driver", "tests.simulated_hardware:nothing"], "has no callable 'nothing'"),
        (
            ["--driver", "tests.simulated_hardware:not_hardware"],
            "expected robots.drivers.interfaces.Hardware",
        ),
        (["--driver", "tests.simulated_hardware"], "expected 'package.module:factory'"),
        (["--hangings", "0"], "--hangings"),
        (["--hangings", "sometimes"], "--hangings"),
        (
            ["--hangings", "auto", "--driver", "tests.simulated_hardware:connect"],
            "needs a driver that can ask for a re-hang",
        ),
    ],
)
def test_bad_driver_or_hangings_is_a_user_error_before_anything_moves(
    tmp_path, args, needle, capfd
):
    r = scanner(capfd, "scan", *args, "--views", "2", "--out", tmp_path / "x")
    assert r.returncode == 2 and needle in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "x").exists()


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_resume_of_a_complete_scan_changes_nothing(tiny_scan, capfd):
    before = _snapshot(tiny_scan.scan_dir)
    r = scanner(capfd, "scan", "--resume", tiny_scan.scan_dir)
    assert r.returncode == 2 and "the scan is complete; nothing was changed" in r.stderr
    assert f"scanner reconstruct {tiny_scan.scan_dir}" in r.stderr
    assert _snapshot(tiny_scan.scan_dir) == before


def test_resume_compares_only_the_options_given():
    from scanner.configs.scan import resume_request

    saved = replace(ScanConfig(object="bracket"), views=replace(ScanConfig().views, count=7))
    assert resume_request(saved, None) == saved
    assert resume_request(saved, None, views=7, object_spec="bracket") == saved
    assert resume_request(saved, None, views=8) != saved
    assert resume_request(saved, None, seed=3).error_model.seed == 3


def test_resume_with_a_config_file_compares_only_its_keys(tmp_path):
    from scanner.configs.scan import resume_request

    saved = ScanConfig(object="bracket")
    path = tmp_path / "views.yaml"
    path.write_text(yaml.safe_dump({"views": {"count": saved.views.count}}))
    assert resume_request(saved, path) == saved
    path.write_text(yaml.safe_dump({"views": {"radius_m": 0.6}}))
    assert resume_request(saved, path).views.radius_m == 0.6


def test_resume_refuses_a_different_object(tiny_scan, tmp_path):
    copy = interrupted_copy(tiny_scan.scan_dir, tmp_path / "interrupted", kept=3)
    with pytest.raises(ScannerError, match="different configuration"):
        run_scan(ScanConfig(object="bracket"), None, resume=copy)
    assert CaptureStore.open(copy).read_manifest()["status"] == "interrupted"


def test_scan_status_never_goes_back(tmp_path):
    store = CaptureStore.create(tmp_path / "s", {"object": "vase"})
    store.update_manifest(status="captured")
    with pytest.raises(AssertionError, match="may not go back"):
        store.update_manifest(status="running")
    store.update_manifest(status="complete")
    with pytest.raises(AssertionError, match="may not go back"):
        store.update_manifest(status="captured")


def test_out_directory_that_is_not_a_scan_is_refused(tmp_path, capfd):
    (tmp_path / "notes.txt").write_text("keep me")
    r = scanner(capfd, "scan", "--out", tmp_path, "--views", "2")
    assert r.returncode == 2 and "not a scan directory" in r.stderr
    assert "Traceback" not in r.stderr
    assert (tmp_path / "notes.txt").read_text() == "keep me"


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--views", "0"], "at least 1 view"),
        (["--radius", "3.0"], "no viewpoint at radius"),
        (["--radius", "0.3"], "use a larger radius"),  # stereo could not match the object
        (["--object", "teacup"], "unknown object"),
    ],
)
def test_bad_scan_input(args, needle, tmp_path, tiny_config_file, capfd):
    r = scanner(capfd, "scan", "--config", tiny_config_file, "--out", tmp_path / "s", *args)
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "s").exists()

"""Faults during long work: kill -9 in the middle of a reconstruction or a calibration leaves no
results folder that looks complete, and a full disk gives a clear error and loses no capture.
The killed run is a separate process; the run after it is in this process (tests.in_process)."""

from __future__ import annotations

import errno
import json
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from reconstruction.calibration.file import load_calibration
from reconstruction.common.errors import StorageError
from reconstruction.config import variant_config
from scanner.configs.scan import load_scan_config
from scanner.scan.run import run_scan
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.manifest import open_scan
from tests.conftest import shared_data
from tests.in_process import scanner
from tests.tiny_scan import TINY_SCAN


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "scanner", *args]


def _wait_for(condition, proc: subprocess.Popen, timeout_s: float = 300) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        if condition():
            return True
        time.sleep(0.005)
    return False


def _status(scan_dir: Path) -> str | None:
    try:
        return yaml.safe_load((scan_dir / "scan.yaml").read_text()).get("status")
    except (OSError, yaml.YAMLError, AttributeError):
        return None


@pytest.fixture(scope="module")
def tiny_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "tiny.yaml"
    path.write_text(yaml.safe_dump({**TINY_SCAN, "views": {**TINY_SCAN["views"], "count": 4}}))
    return path


def test_scan_killed_while_reconstructing_resumes_into_a_complete_result(
    tiny_file, tmp_path, capfd
):
    out = tmp_path / "scan"
    proc = subprocess.Popen(
        _cli("scan", "--config", str(tiny_file), "--out", str(out)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    assert _wait_for(lambda: _status(out) == "captured", proc), "never reached reconstruction"
    time.sleep(1.0)  # well inside the reconstruction (several seconds for 4 views)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert _status(out) == "captured"
    results = out / "results"
    # Only the scan's own report is there: nothing that looks like a reconstruction.
    assert not (results / "reconstruction.yaml").exists()
    assert not list(results.glob("mesh_*"))
    assert json.loads((results / "report.json").read_text())["status"] == "captured"

    r = scanner(capfd, "scan", "--resume", out)
    assert r.returncode == 0, r.stderr
    assert _status(out) == "complete"
    report = json.loads((results / "report.json").read_text())
    assert report["status"] == "complete" and report["views_captured"] == 4
    assert report["chamfer_mm"] > 0 and (results / "reconstruction.yaml").is_file()
    assert not list(out.glob(".results.*"))  # the killed run's partial folder is gone


@pytest.fixture(scope="module")
def tiny_scan_dir(tiny_scan) -> Path:
    return tiny_scan.scan_dir


def test_reconstruct_killed_while_writing_leaves_no_results(tiny_scan_dir, tmp_path, capfd):
    out = tmp_path / "rec"
    # Without ICP: the registration is not what is killed, the writing of the results is.
    args = ["reconstruct", str(tiny_scan_dir), "--no-icp", "--out", str(out)]
    proc = subprocess.Popen(
        _cli(*args),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    # The results are written into a hidden partial folder, renamed at the very end.
    caught = _wait_for(lambda: any(tmp_path.glob(".rec.partial-*")), proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert caught, "the reconstruction finished before its write stage was seen"
    assert not out.exists()
    r = scanner(capfd, *args)
    assert r.returncode == 0, r.stderr
    assert (out / "reconstruction.yaml").is_file() and (out / "report.json").is_file()
    assert not list(tmp_path.glob(".rec.*"))


@pytest.mark.parametrize("delay_s", [1.5, 2.5, 3.5])
def test_calibration_killed_at_any_moment_leaves_nothing_that_looks_complete(
    tmp_path, delay_s, capfd
):
    root = shared_data("real/handeye_open3dv_eye_in_hand_circlegrid")
    out = tmp_path / "cal"
    args = ["calibrate", "--offline", str(root), "--board", "circles_asymmetric"]
    args += ["--board-size", "7x11", "--board-spacing", "0.02", "--inverted"]
    args += ["--pose-convention", "open3dv", "--intrinsics", str(root / "param.txt")]
    proc = subprocess.Popen(
        _cli(*args, "--out", str(out)), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    time.sleep(delay_s)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    results = out / "results"
    if results.exists():  # it finished before the kill: then everything is there
        assert {p.name for p in results.iterdir()} >= {
            "calibration.yaml",
            "report.json",
            "report.txt",
        }
        load_calibration(results / "calibration.yaml")
    r = scanner(capfd, *args, "--out", out, "--force")
    assert r.returncode == 0, r.stderr
    load_calibration(results / "calibration.yaml")
    assert not list(out.glob(".results.*"))


def _full_disk_after(monkeypatch, png_writes: int) -> None:
    """Every capture image write after the first `png_writes` fails with ENOSPC."""
    import scanner.scan_dir.captures

    real = scanner.scan_dir.captures.write_bytes
    count = {"png": 0}

    def write_bytes(path: Path, data: bytes) -> None:
        if path.suffix == ".png":
            count["png"] += 1
            if count["png"] > png_writes:
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, data)

    monkeypatch.setattr(scanner.scan_dir.captures, "write_bytes", write_bytes)


def test_full_disk_stops_the_scan_and_keeps_every_capture(tiny_file, tmp_path, monkeypatch):
    config = replace(load_scan_config(tiny_file), reconstruct=False)
    out = tmp_path / "full"
    _full_disk_after(monkeypatch, png_writes=5)  # two captures, then half of the third
    with pytest.raises(StorageError, match="no space left on the device") as e:
        run_scan(config, out)
    assert "the 2 captures so far are kept" in str(e.value)
    assert f"scanner scan --resume {out}" in str(e.value)
    store = CaptureStore.open(out)
    kept = store.captured_indices()  # in the tour's order, not by number
    assert len(kept) == 2
    assert not list((out / "captures").glob(".tmp-*"))
    assert store.read_manifest()["status"] == "interrupted"
    before = {i: (out / "captures" / f"{i:04d}" / "left.png").read_bytes() for i in kept}
    for i in kept:
        store.read_capture(i)

    monkeypatch.undo()  # space freed
    result = run_scan(None, None, resume=out)
    assert result.report["views_captured"] == 4
    assert CaptureStore.open(out).captured_indices() == [0, 1, 2, 3]
    for i, data in before.items():
        assert (out / "captures" / f"{i:04d}" / "left.png").read_bytes() == data


def test_full_disk_while_writing_results_leaves_no_results(tiny_scan_dir, tmp_path, monkeypatch):
    import scanner.reconstruct.stages

    def no_space(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(scanner.reconstruct.stages, "save_outputs", no_space)
    out = tmp_path / "rec"
    # The writing fails, whatever was registered and meshed: pose-only, the TSDF mesh alone.
    processing = open_scan(tiny_scan_dir).config.processing
    reconstruction = variant_config(processing.reconstruction, "pose_only")
    surfaces = replace(reconstruction.surfaces, methods=("tsdf",))
    processing = replace(
        processing,
        reconstruction=replace(reconstruction, surfaces=surfaces),
        primary_surface="tsdf",
    )
    with pytest.raises(StorageError, match="no space left on the device"):
        scanner.reconstruct.stages.run_reconstruct(tiny_scan_dir, processing, out)
    assert not out.exists() and not list(tmp_path.glob(".rec.*"))

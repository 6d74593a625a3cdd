"""Reconstruction from bad inputs: a damaged capture, and a calibration whose mount is 40 mm /
10 deg off, flagged where the correction cannot get there. The figures these tests check do not
depend on the surfaces, so they build one coarse surface (TSDF at 2 mm) or none of the
registration where that is not what is tested."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
import yaml

from reconstruction.config import variant_config
from scanner.reconstruct.stages import run_reconstruct
from scanner.reports.self_checks import EXIT_SELF_CHECK_FAILED
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.manifest import open_scan
from tests.in_process import scanner
from tests.tiny_scan import TINY_PROCESSING

pytestmark = pytest.mark.slow

# The registration and the hand-eye correction as configured; the TSDF mesh alone as surface,
# on a 2 mm grid, and the truth's metrics on 20,000 samples.
TSDF_ONLY = {
    "reconstruction": {"surfaces": {"methods": ["tsdf"], "tsdf_voxel_size_m": 0.002}},
    "primary_surface": "tsdf",
    "metric_samples": 20_000,
}


def test_a_damaged_capture_is_skipped_and_reported(tiny_scan, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(tiny_scan.scan_dir, copy)
    (copy / "captures" / "0003" / "right.png").write_bytes(b"\x89PNG\r\n\x1a\n cut short")
    store = CaptureStore.open(copy)
    # Which captures are used depends on neither the registration nor the surfaces: pose-only
    # poses and the TSDF mesh alone.
    base = open_scan(copy).config.processing
    tsdf_only = replace(base.reconstruction.surfaces, methods=("tsdf",))
    reconstruction = replace(variant_config(base.reconstruction, "pose_only"), surfaces=tsdf_only)
    processing = replace(base, reconstruction=reconstruction, primary_surface="tsdf")
    run = run_reconstruct(copy, processing, tmp_path / "out", page=False)
    (skipped,) = run.report["captures_skipped"]
    assert skipped["index"] == 3 and "right.png" in skipped["reason"]
    assert run.report["captures_used"] == len(store.captured_indices()) - 1


def _rough_mount_calibration(scan_dir, path):
    """The scan's camera with the TRUE X_FC moved 40 mm / 10 deg (a hand-made mount)."""
    from reconstruction.calibration.file import Calibration, save_calibration
    from reconstruction.common.transforms import twist_to_pose
    from reconstruction.evaluation.metrics import handeye_error
    from scanner.reconstruct.scan_views import load_truth_of

    scan = open_scan(scan_dir)
    X_FC_true = load_truth_of(scan_dir)[0].X_FC
    axis = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
    shift = np.array([0.6, 0.0, -0.8]) * 0.04
    X_FC = X_FC_true @ twist_to_pose([*(np.radians(10.0) * axis), *shift])
    start = handeye_error(X_FC, X_FC_true)
    assert start["handeye_error_mm"] == pytest.approx(40.0, abs=0.1)
    save_calibration(Calibration(X_FC, scan.camera_model, scan.camera_model.left, "test"), path)
    return path


def test_a_rough_mount_from_the_command_line_that_is_not_corrected_is_flagged(
    tiny_scan, tmp_path, capfd
):
    """Where the correction cannot get there, it must say so and keep the nominal-pose cloud:
    a mount 40 mm / 10 deg off on the tiny scan (5 views at 320x240, its own coarse surfaces),
    without the coarse stage. That the correction does get there from such a start is checked
    on synthetic views (test_reconstruction_pipeline.py) and, on full scans from the command
    line's calibration, by scripts/bench_handeye_basin.py (40 mm / 10 deg starts)."""
    calibration = _rough_mount_calibration(tiny_scan.scan_dir, tmp_path / "rough_tiny.yaml")
    config = {
        **TSDF_ONLY,
        "reconstruction": {
            "surfaces": {**TINY_PROCESSING["reconstruction"]["surfaces"], "methods": ["tsdf"]},
            "handeye": {"coarse": {"enabled": False}},
        },
    }
    (tmp_path / "no_coarse.yaml").write_text(yaml.safe_dump(config))
    out = tmp_path / "narrow"
    # Written, but the exit code and the last line say it is not to be trusted.
    r = scanner(
        capfd,
        "reconstruct",
        tiny_scan.scan_dir,
        "--calibration",
        calibration,
        "--config",
        tmp_path / "no_coarse.yaml",
        "--out",
        out,
    )
    assert r.returncode == EXIT_SELF_CHECK_FAILED, r.stderr
    assert r.stdout.strip().splitlines()[-1].startswith("verdict: FAILED its self-checks")
    report = json.loads((out / "report.json").read_text())
    assert report["handeye_error_mm"] > 2.0  # the premise
    assert report["handeye_converged"] is False and report["handeye_diagnosis"]["failures"]
    assert "WARNING: the hand-eye correction did not converge" in r.stdout
    assert "WARNING" in (out / "summary.md").read_text()
    assert (out / "fused_cloud_nominal.ply").stat().st_size > 0

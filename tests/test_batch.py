"""Batch reconstruction on Ray: one task per scan, a line per scan, failures reported without
stopping the others, and the same results as one by one."""

import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import open3d as o3d
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from scanner.commands.main import main
from scanner.configs.scan import load_scan_config
from scanner.reconstruct.batch import check_ray_address
from scanner.reconstruct.command import ReconstructOptions, reconstruct_one
from scanner.scan.run import run_scan
from tests.in_process import scanner_in_fixture
from tests.tiny_scan import TINY_PROCESSING, TINY_SCAN

TINY = {**TINY_SCAN, "reconstruct": False}
# A batch must give what one-by-one runs give, whatever the settings: pose-only registration
# (the ICP and the hand-eye correction have tests of their own), surfaces on a 4 mm grid and
# the truth's metrics on 5,000 samples keep the four runs short.
POSE_ONLY = {
    **TINY_PROCESSING,
    "reconstruction": {
        "surfaces": {
            **TINY_PROCESSING["reconstruction"]["surfaces"],
            "poisson_depth": 5,
            "tsdf_voxel_size_m": 0.004,
            "fused_voxel_size_m": 0.004,
        },
        "icp": {"enabled": False},
        "handeye": {"enabled": False},
    },
    "metric_samples": 5_000,
}


@pytest.fixture(scope="module")
def pose_only_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "pose_only.yaml"
    path.write_text(yaml.safe_dump(POSE_ONLY))
    return path


@pytest.fixture(scope="module")
def two_scans(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch")
    config_file = root / "tiny.yaml"
    dirs = []
    for seed in (0, 1):
        config_file.write_text(yaml.safe_dump({**TINY, "error_model": {"seed": seed}}))
        dirs.append(run_scan(load_scan_config(config_file), root / f"scan{seed}").scan_dir)
    return dirs


def _mesh(path: Path):
    m = o3d.io.read_triangle_mesh(str(path))
    return np.asarray(m.vertices), np.asarray(m.triangles)


def _reconstructed_or_dies(scan_dir: Path, options):
    """What the batch command runs per scan, except that a worker given a scan named "dies"
    exits at once, as one killed or out of memory would."""
    from scanner.commands.reconstruct import reconstruct_saved

    if scan_dir.name == "dies":
        os._exit(3)
    return reconstruct_saved(scan_dir, options)


@pytest.fixture(scope="module")
def batch(two_scans, pose_only_file, tmp_path_factory):
    """`scanner reconstruct` of the two scans, a missing folder and a scan whose worker dies,
    on two workers: one local Ray for the checks of both tests below (starting Ray and its
    workers costs as much as the two reconstructions)."""
    import sys

    from ray import cloudpickle

    import scanner.commands.reconstruct as command

    missing = tmp_path_factory.mktemp("batch-gone") / "gone"
    dies = tmp_path_factory.mktemp("batch-dies") / "dies"
    # Ray's workers cannot import this test module: send the task function by value.
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(command, "reconstruct_saved", _reconstructed_or_dies)
        dirs = [*two_scans, missing, dies]
        run = scanner_in_fixture("reconstruct", *dirs, "--workers", 2, "--config", pose_only_file)
    return SimpleNamespace(run=run, missing=missing, dies=dies)


def test_a_batch_equals_one_by_one_and_reports_each_scan(
    batch, two_scans, pose_only_file, tmp_path
):
    out, missing = batch.run.stdout, batch.missing
    assert batch.run.returncode == 1  # a scan failed
    assert f"{missing}: FAILED: {missing}: not a scan directory (no scan.yaml)" in out
    for scan_dir in two_scans:
        assert f"{scan_dir}: ok, results {scan_dir / 'results'}" in out
    assert "batch: 2 of 4 scans reconstructed" in out
    for scan_dir in two_scans:
        options = ReconstructOptions(config=pose_only_file, out=tmp_path / scan_dir.name)
        alone = reconstruct_one(scan_dir, options)
        for name in ("mesh_poisson.ply", "mesh_tsdf.ply"):
            a = _mesh(scan_dir / "results" / name)
            b = _mesh(alone.results_dir / name)
            np.testing.assert_array_equal(a[0], b[0])
            np.testing.assert_array_equal(a[1], b[1])
        assert (
            alone.report["chamfer_mm"]
            == yaml.safe_load((scan_dir / "results" / "report.json").read_text())["chamfer_mm"]
        )


def test_a_worker_that_dies_is_reported_and_the_others_finish(batch, two_scans):
    lines = batch.run.stdout.splitlines()
    died = [line for line in lines if line.startswith(f"{batch.dies}: ")]
    assert died == [f"{batch.dies}: FAILED: the worker process died (killed or out of memory)"]
    # The others finished, each heard once, whenever the worker died.
    for scan_dir in two_scans:
        assert len([line for line in lines if line.startswith(f"{scan_dir}: ok, ")]) == 1
    assert len([line for line in lines if ": FAILED: " in line or ": ok, " in line]) == 4


def test_a_ray_address_that_does_not_answer_is_a_clear_error():
    with pytest.raises(ScannerError, match="no Ray head answers"):
        check_ray_address("127.0.0.1:9", timeout_s=1.0)
    with pytest.raises(ScannerError, match="expected HOST:PORT"):
        check_ray_address("nowhere")


def test_out_with_several_scans_is_refused(two_scans, tmp_path, capsys):
    rc = main(["reconstruct", *map(str, two_scans), "--out", str(tmp_path / "x")])
    assert rc == 2 and "--out names one results folder" in capsys.readouterr().err

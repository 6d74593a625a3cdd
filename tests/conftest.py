"""Shared fixtures: the simulated world is built once per session (it is the slow part), and the
scans several test files read are built once per test run, whichever worker asks first."""

from __future__ import annotations

import fcntl
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_data(relative: str) -> Path:
    """A file of ../shared/data, or skip the test when the shared folder is absent."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"shared data not available: {path}")
    return path


# The longest test files (seconds of test time on two cores, from `--durations=0`), longest
# first. `make test` hands files to its workers in collection order (--dist loadfile
# --no-loadscope-reorder), and pytest-xdist's own order (files with the most tests first) left
# the end-to-end files, which have few tests, to the end, where one core ran them while the other
# had nothing left. Longest first, the two finish together. A file missing here runs after these.
LONGEST_FIRST = (
    "test_hangings.py",  # 79 s
    "test_failed_hanging.py",  # 74
    "test_reconstruction_pipeline.py",  # 66
    "test_recording_reconstruction.py",  # 60
    "test_calibration_sim.py",  # 60
    "test_auto_hangings.py",  # 55
    "test_faults.py",  # 49
    "test_reconstruct_scan.py",  # 44
    "test_batch.py",  # 35
    "test_rgbd_scan.py",  # 31
    "test_arm_scan.py",  # 30
    "test_emulated_cell.py",  # 28
    "test_view_stream.py",  # 26
    "test_fixture_removal.py",  # 26
    "test_table.py",  # 24
    "test_inspect.py",  # 22
    "test_scan.py",  # 21
    "test_turntable_scan.py",  # 20
    "test_monitor_detector.py",  # 18
    "test_hanging_symmetry.py",  # 17
    "test_mesh_export.py",  # 17
    "test_cell_monitor.py",  # 17
    "test_calibration_offline.py",  # 16
    "test_reconstruction_handeye.py",  # 15
    "test_checked_before_work.py",  # 15
    "test_reconstruction_surfaces.py",  # 14
)


def pytest_configure(config):
    """Each worker keeps freed memory as the command line does, so that its in-process scans
    and reconstructions (most of the suite) run as a user's would."""
    from reconstruction.common.memory import keep_freed_memory

    keep_freed_memory()


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: files stay whole


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Generated objects go to a per-session cache, never to the user's ~/.cache."""
    import os

    os.environ.setdefault("SCANNER_CACHE", str(tmp_path_factory.mktemp("cache")))


@pytest.fixture(scope="session", autouse=True)
def _board_detections_remembered():
    """Each rendered board image is detected once per worker (tests/detection_memo.py)."""
    import scanner.calibrate.offline as offline
    from tests.detection_memo import remembered

    detect = offline.detect_board_or_reason
    offline.detect_board_or_reason = remembered(detect)
    yield
    offline.detect_board_or_reason = detect


@pytest.fixture(scope="session")
def vase_sim():
    from robots.models.workcell import WorkcellConfig
    from robots.simulation.cell import create_simulation
    from robots.simulation.truth import ErrorModel

    return create_simulation(WorkcellConfig(), "vase", ErrorModel(seed=3))


@pytest.fixture(scope="session")
def view_q(vase_sim):
    """A reachable configuration looking at the object (from the preview's search)."""
    from scanner.scan.preview import first_reachable_view

    return first_reachable_view(vase_sim, 0.5)[1]


@pytest.fixture(scope="session")
def run_dir(tmp_path_factory, worker_id) -> Path:
    """A folder every pytest-xdist worker of this run shares (the workers' temp folders' parent;
    a run without workers has its own)."""
    base = tmp_path_factory.getbasetemp()
    return base if worker_id == "master" else base.parent


def built_once(root: Path, name: str, build: Callable[[Path], object]) -> Path:
    """`root / name`, built by `build(path)` by the first worker that asks; the others wait for
    it (a lock file) and read the same folder. A build that failed is tried again by the next."""
    out = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = root / f"{name}.done"
        if not done.exists():
            shutil.rmtree(out, ignore_errors=True)
            build(out)
            done.touch()
    return out


@pytest.fixture(scope="session")
def tiny_scan(run_dir):
    """The tiny simulated scan (5 views at 320x240, reconstructed), shared by every test file:
    READ it only; a test that writes into a scan folder works on a copy (`shutil.copytree`)."""
    import yaml

    from scanner.configs.scan import load_scan_config
    from scanner.scan.run import ScanResult, run_scan
    from tests.tiny_scan import TINY_SCAN

    def build(out: Path) -> None:
        config_file = run_dir / "tiny-scan.yaml"
        config_file.write_text(yaml.safe_dump(TINY_SCAN))
        run_scan(load_scan_config(config_file), out)

    scan_dir = built_once(run_dir, "tiny-scan", build)
    return ScanResult(scan_dir, json.loads((scan_dir / "results" / "report.json").read_text()))


@pytest.fixture(scope="session")
def vase12_scan_dir(run_dir) -> Path:
    """A 12-view scan of the vase at 640x480 (the default camera's field of view) with the
    default error model, captured and not reconstructed; shared like `tiny_scan` (read only).
    Half the default resolution keeps the accuracy the tests on it check (hand-eye within
    0.5 mm, observed surface sub-millimetre) at a quarter of the pixels to match."""
    from dataclasses import replace

    from scanner.configs.scan import ScanConfig, with_overrides
    from scanner.scan.run import run_scan
    from tests.tiny_scan import HALF_RESOLUTION

    def build(out: Path) -> None:
        config = replace(
            with_overrides(ScanConfig(), views=12, seed=0, hangings=1), camera=HALF_RESOLUTION
        )
        run_scan(replace(config, reconstruct=False), out)

    return built_once(run_dir, "vase12-scan", build)

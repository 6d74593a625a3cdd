"""Capture store: round trip, atomicity, refusal to overwrite, damaged captures named."""

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from scanner.scan_dir.captures import Capture, CaptureStore


def _capture(index, count=3, seed=0):
    rng = np.random.default_rng(seed + index)
    X = np.eye(4)
    X[:3, 3] = rng.normal(size=3)
    return Capture(
        index,
        count,
        rng.uniform(-1, 1, 6),
        X,
        12.5 + index,
        rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
        rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
    )


def test_round_trip_is_exact(tmp_path):
    store = CaptureStore.create(tmp_path / "scan", {"object": "vase"})
    written = _capture(2)
    store.write_capture(written)
    back = CaptureStore.open(tmp_path / "scan").read_capture(2)
    assert back.pose_index == 2 and back.pose_count == 3 and back.stamp_s == written.stamp_s
    np.testing.assert_array_equal(back.q_rad, written.q_rad)  # YAML floats round-trip exactly
    np.testing.assert_array_equal(back.X_WF, written.X_WF)
    np.testing.assert_array_equal(back.left, written.left)  # PNG is lossless
    np.testing.assert_array_equal(back.right, written.right)
    assert store.captured_indices() == [2]
    assert store.read_manifest()["object"] == "vase"


def test_existing_capture_is_never_overwritten(tmp_path):
    store = CaptureStore.create(tmp_path / "scan", {})
    store.write_capture(_capture(0))
    with pytest.raises(ScannerError, match="not overwriting"):
        store.write_capture(_capture(0, seed=9))


def test_partial_capture_is_not_a_capture(tmp_path):
    store = CaptureStore.create(tmp_path / "scan", {})
    store.write_capture(_capture(0))
    partial = tmp_path / "scan" / "captures" / ".tmp-0001"
    partial.mkdir()
    (partial / "left.png").write_bytes(b"\x89PNG half")
    assert store.captured_indices() == [0]
    assert store.remove_partial_captures() == [".tmp-0001"]
    assert not partial.exists()


def test_refuses_foreign_or_existing_directories(tmp_path):
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(ScannerError, match="not a scan directory"):
        CaptureStore.create(foreign, {})
    assert (foreign / "holiday.jpg").exists()
    CaptureStore.create(tmp_path / "scan", {}).write_capture(_capture(0))
    with pytest.raises(ScannerError, match="--resume"):
        CaptureStore.create(tmp_path / "scan", {})
    assert (tmp_path / "scan" / "captures" / "0000" / "capture.yaml").exists()


def test_damaged_captures_are_named(tmp_path):
    store = CaptureStore.create(tmp_path / "scan", {})
    for i in range(3):
        store.write_capture(_capture(i))
    d = tmp_path / "scan" / "captures"
    (d / "0000" / "left.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    meta = (d / "0001" / "capture.yaml").read_text()
    (d / "0001" / "capture.yaml").write_text(meta.replace("q_rad:\n-", "q_rad:\n- .nan\n-", 1))
    with pytest.raises(ScannerError, match="0000/left.png: missing or unreadable"):
        store.read_capture(0)
    with pytest.raises(ScannerError, match="q_rad must be a list of finite joint positions"):
        store.read_capture(1)
    assert store.read_capture(2).pose_index == 2


def test_the_format_names_written_stay_those_earlier_versions_wrote(tmp_path):
    """Scan directories written by earlier versions carry these names, and opening checks them:
    renaming a format (a module moved, say) would make every saved scan unreadable."""
    store = CaptureStore.create(tmp_path / "scan", {})
    store.write_capture(_capture(0))
    assert store.read_manifest()["schema"] == "scanner.scan/1"
    capture_yaml = (tmp_path / "scan" / "captures" / "0000" / "capture.yaml").read_text()
    assert "schema: scanner.capture/1" in capture_yaml

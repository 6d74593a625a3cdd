"""A finished simulated scan copied into the state of one that was stopped part-way, without
running and stopping a scan (what stopping leaves is tested on real stops in test_scan.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from scanner.scan_dir.captures import CaptureStore


def interrupted_copy(scan_dir: Path, copy: Path, kept: int) -> Path:
    """`scan_dir` copied to `copy` as if its scan had been stopped after its first `kept`
    captures in the order they were taken: the later captures and the results gone, the
    manifest's status `interrupted`."""
    shutil.copytree(scan_dir, copy)
    store = CaptureStore.open(copy)
    taken = sorted(store.captured_indices(), key=store.capture_stamp_s)
    for index in taken[kept:]:
        shutil.rmtree(copy / "captures" / f"{index:04d}")
    shutil.rmtree(copy / "results", ignore_errors=True)
    manifest = yaml.safe_load((copy / "scan.yaml").read_text())
    manifest["status"] = "interrupted"
    (copy / "scan.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    return copy

"""What the benchmarks share: the folder of benchmark data (meshes/, real/) and a scan of one of
its meshes, made once and reused from a folder the caller keeps (`--scan-root`).

The data folder is $SCANNER_DATA, else `shared/data` beside the repository's checkout (where the
project's data lives); a benchmark that needs it says which folder it looked in."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path

from scanner.configs.scan import ScanConfig, with_overrides
from scanner.scan.run import run_scan

DATA = Path(
    os.environ.get("SCANNER_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data"
)
MESHES = DATA / "meshes"
REAL = DATA / "real"


def require(path: Path, benchmark: str) -> Path:
    """`path`, or exit with one line naming it and how to point the benchmarks at the data."""
    if not path.exists():
        sys.exit(f"{benchmark}: {path} not found (set SCANNER_DATA to the benchmark data folder)")
    return path


def add_scan_options(parser: argparse.ArgumentParser, scan_root_help: str) -> None:
    """--scan-root (keep the scans and reuse them on the next run) and --views."""
    parser.add_argument("--scan-root", type=Path, default=None, help=scan_root_help)
    parser.add_argument("--views", type=int, default=24)


def mesh_scan(mesh_file: str, scan_dir: Path, views: int) -> Path:
    """A captured (not reconstructed) one-hanging scan of a benchmark mesh at 0.2 m, seed 0;
    reused when `scan_dir` holds one already."""
    if not (scan_dir / "scan.yaml").is_file():
        config = with_overrides(
            ScanConfig(),
            object_spec=str(MESHES / mesh_file),
            size_m=0.2,
            views=views,
            seed=0,
            hangings=1,
        )
        run_scan(replace(config, reconstruct=False), scan_dir)
    return scan_dir

"""Benchmark: `scanner import-recording` of a whole IDR/NeuS recording (DTU MVS scan 24: 49
views of 1600x1200 with masks), and what its poses say.

    python scripts/bench_import_recording.py DTU_FOLDER

Prints one JSON line: wall_s (reading, checking and writing the scan directory), views,
size_mb (the scan directory), split_error_px_max (the scene centre projected through each
world_mat and through the imported K, X_WC: the convention check, at its worst),
standoff_m_min/max (camera centre to the scene centre), nearest_baseline_m_min/median/max (each
camera to its nearest neighbour: the baselines pairs of views can give).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from reconstruction.common.transforms import invert, transform_points
from reconstruction.recordings.formats import read_recording
from scanner.recordings.scan_writer import write_recording_scan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help="an IDR/NeuS folder (cameras_sphere.npz)")
    args = parser.parse_args()
    start = time.perf_counter()
    rec = read_recording(args.source)
    with tempfile.TemporaryDirectory() as tmp:
        out = write_recording_scan(rec, Path(tmp) / "scan")
        wall_s = time.perf_counter() - start
        size_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    cams = np.load(next(Path(args.source).glob("cameras*.npz")))
    p_W = cams["scale_mat_0"][:3, 3] * rec.metres_per_unit
    errors, standoffs = [], []
    for v in rec.views:
        P = cams[f"world_mat_{v.index}"][:3]
        x = P @ np.append(p_W / rec.metres_per_unit, 1.0)
        p_C = transform_points(invert(v.X_WC), p_W[None])[0]
        errors.append(np.linalg.norm((v.camera.K @ p_C)[:2] / p_C[2] - x[:2] / x[2]))
        standoffs.append(np.linalg.norm(v.X_WC[:3, 3] - p_W))
    p_WC = np.array([v.X_WC[:3, 3] for v in rec.views])
    d = np.linalg.norm(p_WC[:, None] - p_WC[None], axis=2)
    np.fill_diagonal(d, np.inf)
    nearest = d.min(axis=1)
    print(
        json.dumps(
            {
                "wall_s": round(wall_s, 2),
                "views": len(rec.views),
                "size_mb": round(size_mb, 1),
                "split_error_px_max": float(f"{max(errors):.3g}"),
                "standoff_m_min": round(min(standoffs), 4),
                "standoff_m_max": round(max(standoffs), 4),
                "nearest_baseline_m_min": round(float(nearest.min()), 4),
                "nearest_baseline_m_median": round(float(np.median(nearest)), 4),
                "nearest_baseline_m_max": round(float(nearest.max()), 4),
            }
        )
    )


if __name__ == "__main__":
    main()

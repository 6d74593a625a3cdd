"""Benchmark: the DEFAULTS on real data nobody here made, and the hand-eye solver over seeds.

- opencv_sample: OpenCV's stereo sample (13 pairs, 10x7 squares, taken as 25 mm) calibrated
  without robot poses (`scanner calibrate --offline`): boards found, stereo RMS, rectified
  epipolar error, baseline, focal lengths.
- open3dv: Open3DV's eye-in-hand circle-grid set (8 poses, Yaskawa convention, its intrinsics)
  against the reference X_FC its README gives (OpenCV Tsai).
- middlebury: Tsukuba and Venus with the default StereoParams: density (share of ground-truth
  pixels given a disparity) and bad_1px (% of those off by more than 1 px), beside OpenCV's
  plain SGBM reference from the data's README.
- handeye_seeds: `bench_handeye_seeds.py` (10 seeds of the simulated calibration; `--seeds-json`
  reads a line it printed, `--seed-data DIR` reuses its captures).
`--parts` runs some of them (comma-separated names; all by default).
Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from benchmark_data import REAL, require
from scipy.spatial.transform import Rotation

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.pose_files import pose_format
from reconstruction.stereo.matching import compute_disparity
from scanner.calibrate.offline import (
    OfflineOptions,
    calibrate_cameras_directory,
    calibrate_directory,
)

# Open3DV's README: X_FC by OpenCV Tsai (mm, rotation vector).
OPEN3DV_T_M = np.array([219.96, 68.97, -177.71]) * 1e-3
OPEN3DV_ROTVEC = np.array([0.1004, -0.0459, 1.5495])
# name: (left, right, truth, truth scale, disparities, OpenCV SGBM bad % where it answered)
MIDDLEBURY = {
    "tsukuba": ("im3.png", "im4.png", "disp3.pgm", 16, 16, 4.8),
    "venus": ("im2.png", "im6.png", "disp2.pgm", 8, 32, 2.0),
}
LEFT_BORDER_PX = 20  # no match can exist within d_max of the left border


def opencv_sample(out: Path) -> dict:
    board = BoardSpec("chessboard", 10, 7, 0.025)
    run = calibrate_cameras_directory(
        REAL / "stereo_calibration_opencv_sample", OfflineOptions(board), _settings(), out
    )
    r = run.report
    return {
        "boards_found": r["boards_found"] + r["boards_found_right"],
        "images": 2 * r["images"],
        "stereo_rms_px": round(r["stereo_rms_px"], 4),
        "epipolar_median_px": round(r["epipolar_median_px"], 4),
        "epipolar_p95_px": round(r["epipolar_p95_px"], 4),
        "baseline": round(r["baseline_m"], 5),
        "baseline_squares": round(r["baseline_m"] / 0.025, 3),
        "focal_px": [round(f, 2) for f in r["focal_px"]],
    }


def _settings():
    from reconstruction.calibration.settings import CalibrationSettings

    return CalibrationSettings()


def open3dv(out: Path) -> dict:
    root = REAL / "handeye_open3dv_eye_in_hand_circlegrid"
    options = OfflineOptions(
        BoardSpec("circles_asymmetric", 7, 11, 0.02, inverted=True),
        pose_format("open3dv"),
        intrinsics=root / "param.txt",
    )
    run = calibrate_directory(root, options, _settings(), out)
    X = run.solution.calibration.X_FC
    R_ref = Rotation.from_rotvec(OPEN3DV_ROTVEC).as_matrix()
    return {
        "poses_used": run.report["poses_used"],
        "X_FC_delta_mm": round(float(1e3 * np.linalg.norm(X[:3, 3] - OPEN3DV_T_M)), 3),
        "X_FC_delta_deg": round(
            float(np.degrees(Rotation.from_matrix(X[:3, :3].T @ R_ref).magnitude())), 4
        ),
    }


def middlebury() -> dict:
    out = {}
    for scene, (left, right, truth, scale, num_d, reference) in MIDDLEBURY.items():
        folder = REAL / "stereo_middlebury" / scene
        rgb = [cv2.cvtColor(cv2.imread(str(folder / f)), cv2.COLOR_BGR2RGB) for f in (left, right)]
        gt = cv2.imread(str(folder / truth), cv2.IMREAD_GRAYSCALE).astype(np.float32) / scale
        disparity = compute_disparity(*rgb, 0, num_d)
        evaluated = gt > 0
        evaluated[:, :LEFT_BORDER_PX] = False
        valid = evaluated & np.isfinite(disparity)
        bad = np.abs(disparity - gt) > 1.0
        out[scene] = {
            "density": round(float(valid.sum() / evaluated.sum()), 4),
            "bad_1px": round(float(100 * bad[valid].mean()), 3),
            "opencv_reference_bad_1px": reference,
        }
    return out


PARTS = ("opencv_sample", "open3dv", "middlebury", "handeye_seeds")


def _parts(text: str) -> list[str]:
    parts = [p.strip() for p in text.split(",") if p.strip()]
    unknown = [p for p in parts if p not in PARTS]
    if unknown or not parts:
        raise argparse.ArgumentTypeError(f"expected some of {', '.join(PARTS)}, got {text!r}")
    return parts


def handeye_seeds(seeds_json: Path | None, seed_data: Path | None) -> dict:
    if seeds_json is not None:
        return json.loads(seeds_json.read_text())
    cmd = [sys.executable, str(Path(__file__).with_name("bench_handeye_seeds.py"))]
    if seed_data is not None:
        cmd += ["--data", str(seed_data)]
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds-json", type=Path, help="a line bench_handeye_seeds.py printed")
    parser.add_argument("--seed-data", type=Path, help="reuse bench_handeye_seeds' captures")
    parser.add_argument(
        "--parts", type=_parts, default=list(PARTS), help=f"some of {','.join(PARTS)} (all)"
    )
    args = parser.parse_args()
    require(REAL, "bench_real")
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        if "opencv_sample" in args.parts:
            result["opencv_sample"] = opencv_sample(Path(tmp) / "sample")
        if "open3dv" in args.parts:
            result["open3dv"] = open3dv(Path(tmp) / "open3dv")
        if "middlebury" in args.parts:
            result["middlebury"] = middlebury()
    if "handeye_seeds" in args.parts:
        seeds = handeye_seeds(args.seeds_json, args.seed_data)
        result["handeye_seeds"] = {k: v for k, v in seeds.items() if k.endswith(("_mm", "_deg"))}
        result["handeye_refined_beats_every_method"] = seeds["handeye_refined_beats_every_method"]
    print(json.dumps(result))


if __name__ == "__main__":
    main()

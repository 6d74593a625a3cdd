"""Benchmark: simulated eye-in-hand calibration (default config, default error model) and
eye-to-hand calibration, against the simulator's truth.

Prints one JSON line (millimetres and degrees, for people):
  handeye_error_mm, handeye_error_deg        our refined X_FC
  <method>_error_mm, <method>_error_deg      each OpenCV calibrateHandEye method alone
  reprojection_rms_px                        stereo calibration RMS (both cameras)
  focal_error_px, baseline_error_mm          the stereo calibration against the true cameras
  handeye_reprojection_rms_px                hand-eye RMS with the robot poses as reported
  poses, poses_outliers                      poses used, poses rejected as outliers
  eye_to_hand_mean_mm, eye_to_hand_std_mm    held-out distance error (KTH report: ~8 mm)
  eye_to_hand_points                         held-out points measured
  eye_to_hand_fit_points                     grid points used in the fit, of eye_to_hand_grid
  calibrate_s                                the whole eye-in-hand run: plan, capture, solve
  solve_s, eye_to_hand_s
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.eye_in_hand import run_eye_in_hand
from scanner.calibrate.eye_to_hand import run_eye_to_hand


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        os.environ.setdefault("SCANNER_CACHE", str(Path(tmp) / "cache"))
        config = CalibrateConfig()
        run = run_eye_in_hand(config, Path(tmp) / "eye_in_hand")
        e2h = run_eye_to_hand(config, Path(tmp) / "eye_to_hand")
    report, truth = run.report, run.report["truth"]
    out = {
        "handeye_error_mm": round(truth["handeye_error_mm"], 4),
        "handeye_error_deg": round(truth["handeye_error_deg"], 5),
    }
    for name, e in truth["opencv"].items():
        out[f"{name}_error_mm"] = round(e["handeye_error_mm"], 4)
        out[f"{name}_error_deg"] = round(e["handeye_error_deg"], 5)
    out.update(
        {
            "reprojection_rms_px": round(report["stereo_rms_px"], 4),
            "focal_error_px": [round(v, 4) for v in truth["focal_error_px"]],
            "baseline_error_mm": round(truth["baseline_error_mm"], 4),
            "handeye_reprojection_rms_px": round(report["reprojection_rms_px"], 4),
            "poses": report["poses_used"],
            "poses_outliers": report["poses_outliers"],
            "eye_to_hand_mean_mm": round(e2h["held_out"]["mean_distance_mm"], 4),
            "eye_to_hand_std_mm": round(e2h["held_out"]["std_distance_mm"], 4),
            "eye_to_hand_points": e2h["held_out"]["count"],
            "eye_to_hand_fit_points": e2h["fit_points_used"],
            "eye_to_hand_grid": e2h["grid_points"],
            "calibrate_s": round(report["calibrate_s"], 2),
            "solve_s": round(report["solve_s"], 2),
            "eye_to_hand_s": round(e2h["eye_to_hand_s"], 2),
        }
    )
    print(json.dumps(out))


if __name__ == "__main__":
    main()

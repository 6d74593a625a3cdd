"""Benchmark: how far to trust a hand-eye calibration. Over error-model seeds 0..N-1 of the
simulated eye-in-hand calibration (the default 20 stations, the seeded encoder offsets, corner
noise as measured on the renders; without rendering, seconds a seed):

- sigma: with the robot's kinematic errors on (link lengths off by a vector of norm drawn in
  0.5-1 mm per calibration, the solver told the arm's accuracy, 0.5 mm), every axis of the true
  X_FC error in units of its reported sigma; honest: >= 9 of 10 runs within 3 sigma, and not
  uselessly wide: `mean_ratio` (over runs and axes) within 0.3-1.5 with link errors. Beside it,
  the bootstrap sigma and the reported sigma against the observed RMS error over the runs, per
  axis (the bootstrap sees what differs from view to view; an error the same in every view of a
  calibration it cannot see);
- robot offsets on the same runs: the true encoder offsets against the estimates on the joints
  found observable (`runs_all_offsets_within_0.005deg`), X_FC's error and held-out prediction
  without and with them (`runs_X_FC_closer`, `runs_held_out_better`: runs where estimating the
  offsets helped); and once more with the encoder offsets alone (no link errors): there every
  run recovers its offsets within 0.005 deg, predicts better and comes closer;
- real data (`--real DIR`, an Open3DV-style folder of images, poses `posK.txt` and intrinsics
  `param.txt`, a 7x11 asymmetric circle grid of 20 mm, white on black): held-out prediction of
  the chosen X_FC and of every closed-form method.

`--rendered` runs instead the sigma check on rendered calibrations (a minute a seed; `--data DIR`
keeps the captures in DIR/seedK and solves them again on later runs), with the default error
model (encoder offsets only: the rendered arm has the drawn link lengths).

Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.sigma_check import error_in_sigmas, render_free_observations, summarise

KINEMATIC_ERROR_M = (0.0005, 0.001)
ARM_ACCURACY_M = 0.0005
OFFSET_TOLERANCE_DEG = 0.005
AXES = ("rx_deg", "ry_deg", "rz_deg", "x_mm", "y_mm", "z_mm")


def _axes(values: np.ndarray) -> dict:
    """Twist-ordered (rad, m) values as degrees and millimetres per axis."""
    scale = np.r_[np.full(3, math.degrees(1.0)), np.full(3, 1e3)]
    return {a: round(float(v), 5) for a, v in zip(AXES, np.asarray(values) * scale)}


def _sigma_and_offsets(seeds: int, kinematic_error_m, solver) -> dict:
    from reconstruction.calibration.eye_in_hand import calibrate_hand_eye
    from reconstruction.common.transforms import invert, pose_difference, pose_to_twist
    from robots.arms.rx60 import arm_model

    config = CalibrateConfig()
    stereo = config.camera.stereo_camera()
    arm = arm_model()
    ratios, errors, boot, reported, common = [], [], [], [], []
    offset_errors, without_mm, with_mm, held_without, held_with, kept = [], [], [], [], [], 0
    for observations, X_FC_true, offsets_true in render_free_observations(
        config, range(seeds), kinematic_error_m
    ):
        he = calibrate_hand_eye(config.board, observations, stereo, solver)
        ratios.append(error_in_sigmas(he.X_FC, he.X_FC_sigma, X_FC_true))
        errors.append(pose_to_twist(invert(he.X_FC) @ X_FC_true))
        boot.append(he.quality.bootstrap_sigma)
        common.append(he.quality.common_sigma)
        reported.append(he.X_FC_sigma)
        ho = calibrate_hand_eye(
            config.board, observations, stereo, solver, arm=arm, robot_offsets=True
        )
        e = ho.robot_errors
        joints = [k for k in e.estimated if k < 6]
        estimate = ho.robot_errors.params if e.kept else np.zeros(arm.size)
        offset_errors.append(np.degrees(np.abs(estimate[joints] - offsets_true[joints])))
        without_mm.append(1e3 * pose_difference(he.X_FC, X_FC_true)[0])
        with_mm.append(1e3 * pose_difference(ho.X_FC, X_FC_true)[0])
        held_without.append(e.held_out_px_without)
        held_with.append(e.held_out_px_with)
        kept += e.kept
    observed = np.sqrt(np.mean(np.square(errors), axis=0))
    largest = np.max(reported, axis=0)
    boot_within = int(sum(bool(np.all(b[3:] <= r[3:])) for b, r in zip(boot, reported)))
    boot, reported = np.mean(boot, axis=0), np.mean(reported, axis=0)
    common = np.mean(common, axis=0)
    summary = summarise(ratios)
    worst_offset = max(float(np.max(v)) if len(v) else 0.0 for v in offset_errors)
    return {
        "sigma": {
            **summary.as_dict(),
            "mean_ratio": round(float(np.mean(ratios)), 3),
            "observed_rms_error": _axes(observed),
            "mean_bootstrap_sigma": _axes(boot),
            "mean_reported_sigma": _axes(reported),
            "max_reported_sigma": _axes(largest),
            "runs_bootstrap_translation_within_reported": boot_within,
            "mean_common_robot_sigma": _axes(common),
            "bootstrap_over_observed": [round(float(v), 3) for v in boot / observed],
            "reported_over_observed": [round(float(v), 3) for v in reported / observed],
        },
        "robot_offsets": {
            "kept": kept,
            "runs_all_offsets_within_0.005deg": int(
                sum(bool(np.all(v < OFFSET_TOLERANCE_DEG)) for v in offset_errors)
            ),
            "worst_offset_error_deg": round(worst_offset, 5),
            "X_FC_error_mm_without": round(float(np.mean(without_mm)), 4),
            "X_FC_error_mm_with": round(float(np.mean(with_mm)), 4),
            "X_FC_error_reduction": round(1 - float(np.mean(with_mm) / np.mean(without_mm)), 3),
            "held_out_px_without": round(float(np.mean(held_without)), 4),
            "held_out_px_with": round(float(np.mean(held_with)), 4),
            "runs_held_out_better": int(sum(w < o for w, o in zip(held_with, held_without))),
            "runs_X_FC_closer": int(sum(w < o for w, o in zip(with_mm, without_mm))),
        },
    }


def _real(root: Path, scratch: Path) -> dict:
    from reconstruction.calibration.boards import BoardSpec
    from reconstruction.calibration.pose_files import pose_format
    from scanner.calibrate.offline import OfflineOptions, calibrate_directory

    options = OfflineOptions(
        BoardSpec("circles_asymmetric", 7, 11, 0.02, inverted=True),
        pose_format("open3dv"),
        intrinsics=root / "param.txt",
    )
    run = calibrate_directory(root, options, CalibrateConfig().solver, out_dir=scratch, force=True)
    held = run.report["held_out"]
    best = min(m["rms_px"] for m in held["methods"].values())
    return {
        "folds": held["folds"],
        "chosen_px": round(held["rms_px"], 4),
        "chosen_mm": round(held["rms_mm"], 4),
        "methods_px": {k: round(v["rms_px"], 4) for k, v in held["methods"].items()},
        "chosen_over_best_method": round(held["rms_px"] / best, 4),
    }


def _rendered(seeds: int, data: Path | None, tmp: Path) -> dict:
    from scanner.calibrate.eye_in_hand import run_eye_in_hand
    from scanner.calibrate.offline import OfflineOptions, calibrate_directory

    ratios = []
    root = data or tmp / "seeds"
    for seed in range(seeds):
        base = CalibrateConfig()
        config = replace(base, error_model=replace(base.error_model, seed=seed))
        where = root / f"seed{seed}"
        if (where / "scan.yaml").is_file() and (where / "truth.yaml").is_file():
            run = calibrate_directory(
                where, OfflineOptions(board=config.board), config.solver, tmp / f"s{seed}", True
            )
        else:
            run = run_eye_in_hand(config, where, force=True)
        ratios.append(run.report["truth"]["X_FC_sigma_ratios"])
    return {"rendered": summarise(ratios).as_dict()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10, help="error-model seeds 0..N-1")
    parser.add_argument("--real", type=Path, help="a real Open3DV-style eye-in-hand folder")
    parser.add_argument("--rendered", action="store_true", help="rendered calibrations")
    parser.add_argument("--data", type=Path, help="with --rendered: keep captures in DIR")
    args = parser.parse_args()
    t0 = time.perf_counter()
    out: dict = {"seeds": args.seeds}
    with tempfile.TemporaryDirectory() as tmp:
        os.environ.setdefault("SCANNER_CACHE", str(Path(tmp) / "cache"))
        if args.rendered:
            out.update(_rendered(args.seeds, args.data, Path(tmp)))
        else:
            solver = replace(
                CalibrateConfig().solver,
                robot_translation_sigma_m=ARM_ACCURACY_M,
            )
            out["kinematic_error_mm"] = [1e3 * v for v in KINEMATIC_ERROR_M]
            out["arm_accuracy_mm"] = 1e3 * ARM_ACCURACY_M
            out["with_link_errors"] = _sigma_and_offsets(args.seeds, KINEMATIC_ERROR_M, solver)
            encoder = _sigma_and_offsets(args.seeds, None, CalibrateConfig().solver)
            out["encoder_offsets_only"] = encoder
            if args.real is not None:
                out["real"] = _real(args.real, Path(tmp) / "real")
    out["bench_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()

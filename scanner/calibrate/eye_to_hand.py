"""`scanner calibrate --eye-to-hand` in simulation: a static stereo camera, a blinking marker on
the flange driven over a 3D grid, a rigid fit with outlier rejection and held-out evaluation."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from pydrake.math import RigidTransform

from planners.ik import look_at_rotation
from reconstruction.calibration.eye_to_hand import (
    MarkerDetectionSettings,
    detect_blinking_marker,
    fit_rigid_robust,
    grid_points,
    held_out_errors,
    triangulate,
)
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, pose_difference, transform_points
from reconstruction.stereo.camera_model import StereoCamera, stereo_camera_to_dict
from robots.arms.default import arm_of
from robots.cache import cache_dir
from robots.simulation.blinking_marker import BlinkingMarker
from robots.simulation.static_camera import StaticStereoCamera
from scanner.calibrate.config import CalibrateConfig, EyeToHandConfig
from scanner.calibrate.eye_in_hand import MoveFn, PlannedMover, build_world
from scanner.calibrate.eye_to_hand_store import (
    POINTS,
    MarkerRecord,
    read_manifest,
    read_points,
    window,
    write_manifest,
    write_point,
)
from scanner.reports.units import deg, mm
from scanner.scan_dir.captures import atomic_write_text
from scanner.scan_dir.results_folder import free_results_dir, require_replaceable, staged_folder


@dataclass(frozen=True, eq=False)
class MarkerMeasurement:
    """One marker position: reported by the robot in W, triangulated in the static camera S."""

    p_W: np.ndarray
    p_S: np.ndarray


def _marker_flange_pose(p_WM: np.ndarray, p_W_camera: np.ndarray, p_FM: np.ndarray) -> np.ndarray:
    """Flange pose putting the marker at p_WM with the tool (and marker) facing the camera."""
    R = look_at_rotation(p_WM, p_W_camera)
    return make_pose(R, p_WM - R @ p_FM)


class _MarkerSession:
    """The simulated cell with the static camera and the marker: moves the marker to points
    and measures it in both images."""

    def __init__(self, config: CalibrateConfig, move_to: MoveFn | None) -> None:
        self.settings = config.eye_to_hand
        flange = arm_of(config.robot).flange_frame
        marker = BlinkingMarker(self.settings.marker, cache_dir() / "markers", flange)
        self.world = build_world(config, extras=(marker,), with_board=False)
        sim = self.world.sim
        self.stereo_S = self.settings.camera.stereo_camera()
        self.camera = StaticStereoCamera(
            sim.workcell,
            sim.truth,
            sim.robot.true_joint_positions,
            self.stereo_S,
            self.settings.camera.X_WS,
            marker,
        )
        self.move_to = move_to or PlannedMover(self.world.planner, sim.robot)
        self.p_FM = np.array(self.settings.marker.p_FM)

    def _reach(self, p_WM: np.ndarray) -> str:
        """Move the marker to p_WM facing the camera; '' when there, else why not."""
        robot = self.world.sim.robot
        X_WF = _marker_flange_pose(p_WM, np.array(self.settings.camera.position_m), self.p_FM)
        q_now = robot.joint_positions()
        qs = [q for q in robot.arm.ik(RigidTransform(X_WF), q_now) if self.world.is_free(q)]
        if not qs:
            return "unreachable or in collision"
        q = min(qs, key=lambda q: float(np.abs(q - q_now).max()))
        return "" if self.move_to(q) else "no collision-free path"

    def _record_here(self, index: int, kind: str) -> MarkerRecord | None:
        """The frames of both cameras cut to a window around the marker, with the reported
        X_WF; None when either camera does not see the marker."""
        lefts, rights = self.camera.blink_frames(self.settings.frames)
        a = detect_blinking_marker(lefts, self.settings.detection)
        b = detect_blinking_marker(rights, self.settings.detection)
        if a is None or b is None:
            return None
        left, left_origin = window(lefts, a.u, a.v)
        right, right_origin = window(rights, b.u, b.v)
        X_WF = self.world.kinematics.X_WF(self.world.sim.robot.joint_positions())
        return MarkerRecord(index, kind, X_WF, left, right, left_origin, right_origin)

    def measure(
        self,
        points: np.ndarray,
        wanted: int,
        progress: Callable[[int, int], None] | None,
        kind: str,
        root: Path,
        first_index: int,
    ) -> tuple[list[MarkerRecord], list[dict]]:
        """Record points in turn (each written to `root`) until `wanted` are measured in both
        cameras or the points run out."""
        done, skipped = [], []
        for p_WM in points:
            if len(done) >= wanted:
                break
            where = [round(float(v), 4) for v in p_WM]
            why = self._reach(p_WM)
            record = None if why else self._record_here(first_index + len(done), kind)
            measured = (
                None
                if record is None
                else measure_record(record, self.stereo_S, self.p_FM, self.settings.detection)
            )
            if measured is None:
                skipped.append({"p_WM": where, "reason": why or "marker not seen by both cameras"})
                continue
            write_point(root, record)
            done.append(record)
            if progress:
                progress(len(done), wanted)
        return done, skipped


def measure_record(
    record: MarkerRecord, stereo: StereoCamera, p_FM: np.ndarray, detection: MarkerDetectionSettings
) -> MarkerMeasurement | None:
    """The marker detected in the recorded windows, triangulated in S, and where the robot
    reported it in W; None when either window does not show it."""
    a = detect_blinking_marker(list(record.left), detection)
    b = detect_blinking_marker(list(record.right), detection)
    if a is None or b is None:
        return None
    (xl, yl), (xr, yr) = record.left_origin_px, record.right_origin_px
    uv_left = np.array([[a.u + xl, a.v + yl]])
    uv_right = np.array([[b.u + xr, b.v + yr]])
    p_S = triangulate(stereo, uv_left, uv_right)[0]
    return MarkerMeasurement(transform_points(record.X_WF, p_FM[None])[0], p_S)


def run_eye_to_hand(
    config: CalibrateConfig,
    out_dir: Path,
    move_to: MoveFn | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Drive the marker over the grid, fit X_WS, evaluate on random held-out points."""
    if config.driver or config.hardware is not None:
        raise ScannerError(
            "eye-to-hand calibration runs in the simulator only (it renders the blinking "
            "marker); drop the driver and the hardware: section"
        )
    t0 = time.perf_counter()
    e2h = config.eye_to_hand
    root = Path(out_dir)
    session = _MarkerSession(config, move_to)
    X_WS_true = e2h.camera.X_WS
    # A replaced run's points must not mix with this run's.
    shutil.rmtree(root / POINTS, ignore_errors=True)
    write_manifest(root, session.stereo_S, session.p_FM, e2h.frames, None)
    grid = grid_points(e2h.grid_center_m, e2h.grid_size_m, e2h.grid_spacing_m)
    fit_points, fit_skipped = session.measure(grid, len(grid), progress, "grid", root, 0)
    if len(fit_points) < 4:
        raise ScannerError(
            f"eye-to-hand: only {len(fit_points)} of {len(grid)} grid points were measured; "
            "need at least 4 not on one line (move the grid where the arm reaches and the "
            "static camera sees the marker)"
        )
    rng = np.random.default_rng(e2h.seed)
    half = np.array(e2h.grid_size_m) / 2
    # Random points in the grid's box until `held_out` are measured (unreachable ones are
    # skipped and reported; at most three draws per wanted point).
    test = np.array(e2h.grid_center_m) + rng.uniform(-half, half, (3 * e2h.held_out, 3))
    test_points, test_skipped = session.measure(
        test, e2h.held_out, progress, "held_out", root, len(fit_points)
    )
    write_manifest(
        root,
        session.stereo_S,
        session.p_FM,
        e2h.frames,
        {
            "X_WS": X_WS_true.tolist(),
            "grid_points": len(grid),
            "skipped_grid": fit_skipped,
            "skipped_held_out": test_skipped,
        },
    )
    report, X_WS = solve_recorded(
        [*fit_points, *test_points],
        session.stereo_S,
        session.p_FM,
        e2h,
        len(grid),
        fit_skipped,
        test_skipped,
        X_WS_true,
    )
    report["eye_to_hand_s"] = time.perf_counter() - t0
    _write_results(root / "results", report, X_WS, session.stereo_S, session.p_FM)
    return report


def solve_recorded(
    records: list[MarkerRecord],
    stereo: StereoCamera,
    p_FM: np.ndarray,
    e2h: EyeToHandConfig,
    grid_count: int,
    fit_skipped: list[dict],
    test_skipped: list[dict],
    X_WS_true: np.ndarray | None,
) -> tuple[dict, np.ndarray]:
    """X_WS from the recorded grid points, evaluated on the held-out ones: the report and X_WS."""
    measured = {"grid": [], "held_out": []}
    for r in records:
        m = measure_record(r, stereo, p_FM, e2h.detection)
        if m is None:
            skipped = fit_skipped if r.kind == "grid" else test_skipped
            skipped.append({"point": r.index, "reason": "marker not found in the recorded frames"})
        else:
            measured[r.kind].append(m)
    fit_points, test_points = measured["grid"], measured["held_out"]
    if len(fit_points) < 4:
        raise ScannerError(
            f"eye-to-hand: only {len(fit_points)} grid points have the marker in both cameras; "
            "need at least 4 not on one line"
        )
    fit = fit_rigid_robust(
        np.array([m.p_W for m in fit_points]),
        np.array([m.p_S for m in fit_points]),
        e2h.max_residual_m,
    )
    errors = held_out_errors(
        np.array([m.p_W for m in test_points]),
        transform_points(fit.X_AB, np.array([m.p_S for m in test_points])),
    )
    report = _report(fit, grid_count, fit_skipped, test_skipped, errors, X_WS_true)
    return report, fit.X_AB


def solve_eye_to_hand_directory(
    root: Path, config: CalibrateConfig, out_dir: Path | None = None, force: bool = False
) -> tuple[dict, Path]:
    """`--eye-to-hand --offline DIR`: solve again from what a run recorded in DIR. Results go
    to out_dir/results, or to the first free DIR/results, DIR/results-2, ..."""
    root = Path(root)
    manifest, stereo, p_FM = read_manifest(root)
    records = read_points(root, int(manifest["frames"]))
    truth = manifest.get("truth") or {}
    if out_dir is None:
        results = free_results_dir(root, "eye_to_hand.yaml")
    else:
        results = Path(out_dir) / "results"
        require_replaceable(results, "eye_to_hand.yaml", force, "calibration")
    X_WS_true = np.array(truth["X_WS"], float) if "X_WS" in truth else None
    report, X_WS = solve_recorded(
        records,
        stereo,
        p_FM,
        config.eye_to_hand,
        int(truth.get("grid_points", sum(r.kind == "grid" for r in records))),
        list(truth.get("skipped_grid", [])),
        list(truth.get("skipped_held_out", [])),
        X_WS_true,
    )
    report["source"] = f"offline:{root}"
    _write_results(results, report, X_WS, stereo, p_FM)
    return report, results


def _report(fit, grid_points_count, fit_skipped, test_skipped, errors, X_WS_true) -> dict:
    report = {
        "X_WS": fit.X_AB.tolist(),
        "grid_points": grid_points_count,
        "fit_points_used": int(len(fit.inliers)),
        "fit_points_rejected": int(len(fit.outliers)),
        "fit_rms_mm": mm(fit.rms_m),
        "skipped_grid": fit_skipped,
        "skipped_held_out": test_skipped,
        "held_out": {
            "count": errors.count,
            "mean_abs_xyz_mm": [mm(v) for v in errors.mean_abs_xyz_m],
            "std_abs_xyz_mm": [mm(v) for v in errors.std_abs_xyz_m],
            "mean_distance_mm": mm(errors.mean_distance_m),
            "std_distance_mm": mm(errors.std_distance_m),
            "max_distance_mm": mm(errors.max_distance_m),
        },
    }
    if X_WS_true is not None:
        dt, dr = pose_difference(fit.X_AB, X_WS_true)
        report["truth"] = {"X_WS_error_mm": mm(dt), "X_WS_error_deg": deg(dr)}
    return report


def _write_results(
    final: Path, report: dict, X_WS: np.ndarray, stereo: StereoCamera, p_FM: np.ndarray
) -> None:
    with staged_folder(final, "eye_to_hand.yaml") as results:
        _write_files(results, report, X_WS, stereo, p_FM)


def _write_files(
    results: Path, report: dict, X_WS: np.ndarray, stereo: StereoCamera, p_FM: np.ndarray
) -> None:
    atomic_write_text(
        results / "eye_to_hand.yaml",
        yaml.safe_dump(
            {
                "schema": "scanner.eye_to_hand/1",
                "X_WS": X_WS.tolist(),
                "static_camera": stereo_camera_to_dict(stereo),
                "marker_p_FM": p_FM.tolist(),
            },
            sort_keys=False,
        ),
    )
    atomic_write_text(results / "eye_to_hand_report.json", json.dumps(report, indent=2) + "\n")
    atomic_write_text(results / "eye_to_hand_report.txt", eye_to_hand_text(report))


def eye_to_hand_text(report: dict) -> str:
    h = report["held_out"]
    a, s = h["mean_abs_xyz_mm"], h["std_abs_xyz_mm"]
    lines = [
        "eye-to-hand calibration (printed in mm and degrees)",
        f"grid: {report['fit_points_used']} points used, {report['fit_points_rejected']} "
        f"rejected, fit RMS {report['fit_rms_mm']:.3f} mm",
        f"held-out points: {h['count']}",
        f"  |x| {a[0]:.3f} +- {s[0]:.3f}   |y| {a[1]:.3f} +- {s[1]:.3f}   "
        f"|z| {a[2]:.3f} +- {s[2]:.3f} mm",
        f"  distance {h['mean_distance_mm']:.3f} +- {h['std_distance_mm']:.3f} mm "
        f"(max {h['max_distance_mm']:.3f} mm; the KTH report: ~8 mm mean)",
    ]
    for name in ("skipped_grid", "skipped_held_out"):
        if report[name]:
            reasons = sorted({s["reason"] for s in report[name]})
            lines.append(f"{name.replace('_', ' ')}: {len(report[name])} ({'; '.join(reasons)})")
    t = report.get("truth")
    if t:
        lines.append(
            f"against the simulator's truth: X_WS {t['X_WS_error_mm']:.3f} mm, "
            f"{t['X_WS_error_deg']:.4f} deg"
        )
    return "\n".join(lines) + "\n"

"""Calibration reports: report.json (SI units, as the calibration file), report.txt (mm and
degrees, for people), and the errors against the simulator's truth."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from reconstruction.calibration.file import save_calibration
from reconstruction.camera_model import StereoCamera
from reconstruction.transforms import matrix_to_rotvec, pose_difference
from scanner.calibrate.solve import Solution
from scanner.captures import atomic_write_text

CALIBRATION_FILE = "calibration.yaml"


def truth_errors(solution: Solution, truth_X_FC: np.ndarray, truth_stereo: StereoCamera) -> dict:
    """Errors against the simulator's truth (SI units): ours and each OpenCV method alone."""
    dt, dr = pose_difference(solution.hand_eye.X_FC, truth_X_FC)
    out = {"handeye_error_m": dt, "handeye_error_rad": dr, "opencv": {}}
    for name, X in solution.hand_eye.opencv.items():
        mt, mr = pose_difference(X, truth_X_FC)
        out["opencv"][name] = {"handeye_error_m": mt, "handeye_error_rad": mr}
    cams = solution.calibration.stereo
    if cams is not None:
        out["focal_error_px"] = [
            float(np.abs(np.diag(c.K)[:2] - np.diag(t.K)[:2]).max())
            for c, t in ((cams.left, truth_stereo.left), (cams.right, truth_stereo.right))
        ]
        out["principal_point_error_px"] = [
            float(np.linalg.norm(c.K[:2, 2] - t.K[:2, 2]))
            for c, t in ((cams.left, truth_stereo.left), (cams.right, truth_stereo.right))
        ]
        out["baseline_error_m"] = abs(cams.baseline_m - truth_stereo.baseline_m)
    return out


def build_report(solution: Solution, truth: dict | None, extra: dict | None = None) -> dict:
    he = solution.hand_eye
    per_pose = []
    for r in he.residuals:
        xi = he.robot_corrections.get(r.name)
        per_pose.append(
            {
                "name": r.name,
                "status": r.status,
                "rms_px": None if math.isnan(r.rms_px) else r.rms_px,
                "robot_correction_m": None if xi is None else float(np.linalg.norm(xi[3:])),
                "robot_correction_rad": None if xi is None else float(np.linalg.norm(xi[:3])),
            }
        )
    report = {
        "source": solution.calibration.source,
        "poses": len(he.residuals),
        "poses_used": len(he.used),
        "poses_outliers": he.outliers,
        "poses_board_not_found": he.not_found,
        "reprojection_rms_px": he.rms_px,
        "reprojection_rms_after_robot_corrections_px": he.corrected_rms_px,
        "stereo_rms_px": None if solution.stereo is None else solution.stereo.rms_px,
        "camera_rms_px": solution.camera_rms_px,
        "per_pose": per_pose,
        "board_scatter_m": he.board_scatter_m.tolist(),
        "board_scatter_max_m": he.board_scatter_max_m,
        "motion": {
            "max_rotation_rad": he.motion.max_rotation_rad,
            "axis_spread_rad": he.motion.axis_spread_rad,
        },
        "hand_eye_seed": he.seed_method,
        "opencv_failed": he.opencv_failed,
        "X_FC": he.X_FC.tolist(),
        "X_FC_opencv": {k: v.tolist() for k, v in he.opencv.items()},
        "X_WB": he.X_WB.tolist(),
        "solve_s": solution.solve_s,
    }
    if truth is not None:
        report["truth"] = truth
    report.update(extra or {})
    return report


def report_text(report: dict) -> str:
    """The report for people: millimetres and degrees (the files hold metres and radians)."""
    mm, deg = 1000.0, 180.0 / math.pi
    lines = [
        f"calibration from {report['source']} (printed in mm and degrees)",
        f"poses: {report['poses_used']} used of {report['poses']}",
    ]
    if report["poses_outliers"]:
        lines.append(f"  rejected as outliers: {', '.join(report['poses_outliers'])}")
    if report["poses_board_not_found"]:
        lines.append(f"  board not found in: {', '.join(report['poses_board_not_found'])}")
    if report.get("stereo_rms_px") is not None:
        lines.append(f"stereo calibration RMS: {report['stereo_rms_px']:.3f} px")
    if report.get("camera_rms_px") is not None:
        lines.append(f"camera calibration RMS: {report['camera_rms_px']:.3f} px")
    lines.append(
        f"hand-eye reprojection RMS: {report['reprojection_rms_px']:.3f} px with the robot poses "
        f"as reported, {report['reprojection_rms_after_robot_corrections_px']:.3f} px after "
        "the small robot-pose corrections"
    )
    s = np.array(report["board_scatter_m"]) * mm
    lines.append(
        f"board-in-base scatter (std x y z): {s[0]:.2f} {s[1]:.2f} {s[2]:.2f} mm, "
        f"max {report['board_scatter_max_m'] * mm:.2f} mm"
    )
    X = np.array(report["X_FC"])
    rv = matrix_to_rotvec(X[:3, :3])
    lines.append(
        f"X_FC: t = ({', '.join(f'{v * mm:.2f}' for v in X[:3, 3])}) mm, rotation vector = "
        f"({', '.join(f'{v * deg:.3f}' for v in rv)}) deg; seed method {report['hand_eye_seed']}"
    )
    lines.append("per pose (RMS px, robot correction mm / deg):")
    for p in report["per_pose"]:
        rms = "   -  " if p["rms_px"] is None else f"{p['rms_px']:6.3f}"
        corr = ""
        if p["robot_correction_m"] is not None:
            corr = (
                f"  {p['robot_correction_m'] * mm:.3f} mm / "
                f"{p['robot_correction_rad'] * deg:.4f} deg"
            )
        lines.append(f"  {p['name']:>12}  {rms}  {p['status']}{corr}")
    truth = report.get("truth")
    if truth:
        lines.append(
            f"against the simulator's truth: hand-eye {truth['handeye_error_m'] * mm:.3f} mm, "
            f"{truth['handeye_error_rad'] * deg:.4f} deg"
        )
        for name, e in truth["opencv"].items():
            lines.append(
                f"  OpenCV {name:<10} alone: {e['handeye_error_m'] * mm:.3f} mm, "
                f"{e['handeye_error_rad'] * deg:.4f} deg"
            )
        if "focal_error_px" in truth:
            lines.append(
                f"  focal length error {max(truth['focal_error_px']):.3f} px, principal point "
                f"{max(truth['principal_point_error_px']):.3f} px, baseline "
                f"{truth['baseline_error_m'] * mm:.3f} mm"
            )
    return "\n".join(lines) + "\n"


def write_results(out_dir: Path, solution: Solution, report: dict) -> Path:
    results = Path(out_dir) / "results"
    results.mkdir(parents=True, exist_ok=True)
    path = save_calibration(solution.calibration, results / CALIBRATION_FILE)
    atomic_write_text(results / "report.json", json.dumps(report, indent=2) + "\n")
    atomic_write_text(results / "report.txt", report_text(report))
    return path


"""Calibration reports: report.json and report.txt (accuracy figures in mm and degrees, poses in
metres: the rule of scanner.reports.units), and the errors against the simulator's truth."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from reconstruction.calibration.camera_quality import epipolar_error
from reconstruction.calibration.file import save_calibration
from reconstruction.calibration.held_out import MIN_VIEWS_FOR_K_FOLD
from reconstruction.common.transforms import matrix_to_rotvec
from reconstruction.evaluation.metrics import handeye_error
from reconstruction.stereo.camera_model import StereoCamera
from scanner.calibrate.corners import CornerPicture, ImageLoader, write_pictures
from scanner.calibrate.judge import figure_lines, overall
from scanner.calibrate.sigma_check import error_in_sigmas
from scanner.calibrate.solve import Solution, x_fc_sigma_record
from scanner.reports.units import deg, mm
from scanner.scan_dir.captures import atomic_write_text
from scanner.scan_dir.outputs import CALIBRATION_FILE
from scanner.scan_dir.results_folder import staged_folder


def truth_errors(
    solution: Solution,
    truth_X_FC: np.ndarray,
    truth_stereo: StereoCamera,
    truth_joint_offsets_rad: np.ndarray | None = None,
) -> dict:
    """Errors against the simulator's truth: ours and each OpenCV method alone; with the true
    joint offsets, the error of each estimated one."""
    he = solution.hand_eye
    out = {**handeye_error(he.X_FC, truth_X_FC), "opencv": {}}
    errors = he.robot_errors
    if truth_joint_offsets_rad is not None and errors is not None and errors.estimated:
        out["joint_offset_errors_deg"] = {
            f"joint {k + 1}": deg(errors.params[k] - truth_joint_offsets_rad[k])
            for k in errors.estimated
            if k < 6
        }
    # |error| / sigma per axis (rotation x y z, translation x y z in C): the sigma's honesty.
    out["X_FC_sigma_ratios"] = [
        float(v) for v in error_in_sigmas(he.X_FC, he.X_FC_sigma, truth_X_FC)
    ]
    for name, X in solution.hand_eye.opencv.items():
        out["opencv"][name] = handeye_error(X, truth_X_FC)
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
        out["baseline_error_mm"] = mm(abs(cams.baseline_m - truth_stereo.baseline_m))
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
                "robot_correction_mm": None if xi is None else mm(np.linalg.norm(xi[3:])),
                "robot_correction_deg": None if xi is None else deg(np.linalg.norm(xi[:3])),
            }
        )
    report = {
        "source": solution.calibration.source,
        "poses": len(he.residuals),
        "poses_used": len(he.used),
        "poses_outliers": he.outliers,
        "poses_board_not_found": he.not_found,
        "board_not_found_reasons": {
            o.name: o.not_found for o in solution.observations if o.left is None and o.not_found
        },
        "reprojection_rms_px": he.rms_px,
        "reprojection_rms_after_robot_corrections_px": he.corrected_rms_px,
        "hand_eye_pixel_sigma_px": he.pixel_sigma_px,
        "stereo_rms_px": None if solution.stereo is None else solution.stereo.rms_px,
        "camera_rms_px": solution.camera_rms_px,
        "per_pose": per_pose,
        "board_scatter_mm": [mm(s) for s in he.board_scatter_m],
        "board_scatter_max_mm": mm(he.board_scatter_max_m),
        "motion": {
            "max_rotation_rad": he.motion.max_rotation_rad,
            "axis_spread_rad": he.motion.axis_spread_rad,
        },
        "hand_eye_seed": he.seed_method,
        "opencv_failed": he.opencv_failed,
        "X_FC": he.X_FC.tolist(),
        "X_FC_sigma": x_fc_sigma_record(he.X_FC_sigma),
        "X_FC_sigma_mm": mm(np.max(he.X_FC_sigma[3:])),
        "X_FC_sigma_deg": deg(np.max(he.X_FC_sigma[:3])),
        "X_FC_opencv": {k: v.tolist() for k, v in he.opencv.items()},
        "X_WB": he.X_WB.tolist(),
        "solve_s": solution.solve_s,
    }
    stereo = solution.calibration.stereo
    if stereo is not None:
        found = [o for o in solution.observations if o.left is not None and o.right is not None]
        if found:
            report["epipolar_median_px"] = epipolar_error(stereo, found).median_px
    report.update(quality_report(he))
    if truth is not None:
        report["truth"] = truth
    report.update(extra or {})
    return report


def quality_report(he) -> dict:
    """The report keys of the held-out prediction, the sigma's sources and the robot errors."""
    out: dict = {}
    q = he.quality
    if q is not None:
        loo = q.folds.leave_one_out and len(q.folds.groups) < MIN_VIEWS_FOR_K_FOLD
        out["held_out"] = {
            "folds": q.folds.words(),
            "rms_px": q.held_out.rms_px,
            "rms_mm": mm(q.held_out.rms_m),
            "methods": {name: e.as_dict() for name, e in q.held_out_methods.items()},
            "best_method": q.best_method,
            "disagreement_sigmas": q.disagreement_sigmas,
            "methods_note": q.note,
            "leave_one_out_note": (
                f"only {len(q.folds.groups)} views used: held out one at a time (leave-one-out) "
                f"instead of k folds, which need at least {MIN_VIEWS_FOR_K_FOLD}"
                if loo
                else ""
            ),
        }
        # The judged figure (scanner.calibrate.judge): what a scan's uncorrected pose predicts.
        out["held_out_mm"] = mm(q.held_out.rms_m)
        cov, boot = he.X_FC_covariance_sigma, q.bootstrap_sigma
        out["X_FC_sigma_covariance"] = x_fc_sigma_record(cov)
        out["X_FC_sigma_bootstrap"] = x_fc_sigma_record(boot)
        out["X_FC_sigma_sources"] = {
            "reported_mm": mm(np.max(he.X_FC_sigma[3:])),
            "reported_deg": deg(np.max(he.X_FC_sigma[:3])),
            "covariance_mm": mm(np.max(cov[3:])),
            "bootstrap_mm": mm(np.max(boot[3:])),
            "bootstrap_samples": q.bootstrap_samples,
        }
    if he.robot_errors is not None:
        out["robot_errors"] = he.robot_errors.as_dict()
    return out


def quality_lines(report: dict) -> list[str]:
    """Held-out prediction, the methods' agreement, X_FC's uncertainty and the robot errors'
    outcome, as `scanner calibrate` prints them."""
    lines = []
    h = report.get("held_out")
    if h:
        methods = ", ".join(
            f"{name} {m['rms_px']:.3f} px"
            for name, m in sorted(h["methods"].items(), key=lambda item: item[1]["rms_px"])
        )
        lines.append(
            f"held-out prediction ({h['folds']}): {h['rms_px']:.3f} px, {h['rms_mm']:.3f} mm on "
            f"the board; closed-form methods: {methods}"
        )
        if h.get("leave_one_out_note"):
            lines.append(h["leave_one_out_note"])
        if h.get("methods_note"):
            lines.append(f"note: {h['methods_note']}")
    s = report.get("X_FC_sigma_sources")
    if s:
        lines.append(
            f"X_FC 1-sigma: {s['reported_mm']:.3f} mm / {s['reported_deg']:.4f} deg (largest "
            f"axis; covariance {s['covariance_mm']:.3f} mm, bootstrap over views "
            f"{s['bootstrap_mm']:.3f} mm)"
        )
    robot = report.get("robot_errors")
    if robot:
        lines.append(robot["note"])
    return lines


def report_text(report: dict) -> str:
    """The report for people (mm and degrees, as report.json)."""
    lines = [
        f"calibration from {report['source']} (printed in mm and degrees)",
        f"verdict: {overall(report)} (the worst of the figures below)",
        *figure_lines(report),
    ]
    if report.get("options"):
        lines.append("options: " + ", ".join(f"{k} {v}" for k, v in report["options"].items()))
    lines.append(f"poses: {report['poses_used']} used of {report['poses']}")
    if report["poses_outliers"]:
        lines.append(f"  rejected as outliers: {', '.join(report['poses_outliers'])}")
    if report["poses_board_not_found"]:
        reasons = report.get("board_not_found_reasons", {})
        lines.append(
            "  board not found in: "
            + ", ".join(
                f"{name} ({reasons[name]})" if name in reasons else name
                for name in report["poses_board_not_found"]
            )
        )
    if report.get("stereo_rms_px") is not None:
        lines.append(f"stereo calibration RMS: {report['stereo_rms_px']:.3f} px")
    if report.get("camera_rms_px") is not None:
        lines.append(f"camera calibration RMS: {report['camera_rms_px']:.3f} px")
    lines.append(
        f"hand-eye reprojection RMS: {report['reprojection_rms_px']:.3f} px with the robot poses "
        f"as reported, {report['reprojection_rms_after_robot_corrections_px']:.3f} px after "
        "the small robot-pose corrections"
    )
    if report.get("hand_eye_pixel_sigma_px") is not None:
        lines.append(
            f"  images weighed with a board point sigma of {report['hand_eye_pixel_sigma_px']:.3f}"
            " px against the robot-pose accuracy"
        )
    s = report["board_scatter_mm"]
    lines.append(
        f"board-in-base scatter (std x y z): {s[0]:.2f} {s[1]:.2f} {s[2]:.2f} mm, "
        f"max {report['board_scatter_max_mm']:.2f} mm"
    )
    X = np.array(report["X_FC"])
    rv = matrix_to_rotvec(X[:3, :3])
    lines.append(
        f"X_FC: t = ({', '.join(f'{mm(v):.2f}' for v in X[:3, 3])}) mm, rotation vector = "
        f"({', '.join(f'{deg(v):.3f}' for v in rv)}) deg; seed method {report['hand_eye_seed']}"
    )
    sigma = report.get("X_FC_sigma")
    if sigma:
        lines.append(
            "X_FC 1-sigma in the camera frame C: rotation "
            f"({', '.join(f'{deg(v):.4f}' for v in sigma['rotation_rad'])}) deg about x y z, "
            f"translation ({', '.join(f'{mm(v):.3f}' for v in sigma['translation_m'])}) mm"
        )
    lines += quality_lines(report)
    corners = report.get("corner_pictures")
    if corners:
        lines.append(
            f"corner pictures: {len(corners)} in corners/, worst first (detected corners: green "
            f"circles, reprojected by the calibration: red crosses); worst {corners[0]}"
        )
    lines.append("per pose (RMS px, robot correction mm / deg):")
    for p in report["per_pose"]:
        rms = "   -  " if p["rms_px"] is None else f"{p['rms_px']:6.3f}"
        corr = ""
        if p["robot_correction_mm"] is not None:
            corr = f"  {p['robot_correction_mm']:.3f} mm / {p['robot_correction_deg']:.4f} deg"
        lines.append(f"  {p['name']:>12}  {rms}  {p['status']}{corr}")
    truth = report.get("truth")
    if truth:
        lines += _truth_lines(truth)
    return "\n".join(lines) + "\n"


def error_text(errors: dict) -> str:
    """'0.110 mm, 0.0084 deg' of a handeye_error record."""
    return f"{errors['handeye_error_mm']:.3f} mm, {errors['handeye_error_deg']:.4f} deg"


def _truth_lines(truth: dict) -> list[str]:
    lines = [f"against the simulator's truth: hand-eye {error_text(truth)}"]
    if "X_FC_sigma_ratios" in truth:
        lines.append(
            "  error / sigma per axis (rotation x y z, translation x y z): "
            + " ".join(f"{v:.2f}" for v in truth["X_FC_sigma_ratios"])
        )
    for name, e in truth["opencv"].items():
        lines.append(f"  OpenCV {name:<10} alone: {error_text(e)}")
    if "focal_error_px" in truth:
        lines.append(
            f"  focal length error {max(truth['focal_error_px']):.3f} px, principal point "
            f"{max(truth['principal_point_error_px']):.3f} px, baseline "
            f"{truth['baseline_error_mm']:.3f} mm"
        )
    return lines


def write_results(
    results_dir: Path,
    solution: Solution,
    report: dict,
    pictures: list[CornerPicture] = (),
    load_image: ImageLoader | None = None,
) -> Path:
    """calibration.yaml, report.json, report.txt and the corner pictures (corners/), all or
    nothing (a staged folder)."""
    with staged_folder(results_dir, CALIBRATION_FILE) as staging:
        if pictures and load_image is not None:
            write_pictures(staging / "corners", pictures, load_image)
        atomic_write_text(staging / "report.json", json.dumps(report, indent=2) + "\n")
        atomic_write_text(staging / "report.txt", report_text(report))
        save_calibration(solution.calibration, staging / CALIBRATION_FILE)
    return Path(results_dir) / CALIBRATION_FILE

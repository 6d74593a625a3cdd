"""`scanner reconstruct SCAN_DIR` (and the end of `scanner scan`): captures -> measured model.

Stages, each timed in the report, reading the scan directory and writing only under the
results folder (captures are never modified):

    stereo      every capture: rectify, SGBM over the object's depth window, cloud in C
    reconstruct filter, remove robot/cell points (Drake geometry at the recorded joints),
                ICP + pose graph, hand-eye correction, fused cloud, Poisson / TSDF meshes
    evaluate    when truth.yaml is present: surface metrics and hand-eye error vs the truth
    write       fused_cloud.ply, mesh_*.ply (+ .obj/.stl on request), reconstruction.yaml,
                plots; then report.json (merged with the scan's) and summary.md
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from reconstruction.camera_model import StereoCamera
from reconstruction.errors import ScannerError
from reconstruction.metrics import TriangleSurface, evaluate_surface, handeye_error
from reconstruction.outputs import save_outputs, summary
from reconstruction.pipeline import ReconstructionConfig, ReconstructionResult, reconstruct_views
from reconstruction.stage_timer import StageTimer
from reconstruction.stereo.cloud import depth_image, view_cloud
from reconstruction.stereo.params import StereoParams
from reconstruction.stereo.rectification import Rectification, compute_rectification
from reconstruction.views import ViewCloud
from robots.workcell import keep_out_radius_m
from scanner.captures import atomic_write_text
from scanner.config import ProcessingConfig, ScanConfig
from scanner.manifest import SavedScan, open_scan
from scanner.results_folder import free_results_dir, holds_result, staged_folder
from scanner.typed_yaml import load_yaml_file, to_dict

log = logging.getLogger("scanner.reconstruct")


@dataclass(frozen=True, eq=False)
class ReconstructRun:
    result: ReconstructionResult
    report: dict
    results_dir: Path


@dataclass(frozen=True, eq=False)
class CaptureViews:
    """The stereo stage's output: a view per readable capture, the captures skipped (index and
    reason), and the measured joint positions of each view (for the robot/cell point filter)."""

    views: list[ViewCloud]
    skipped: list[dict]
    joints: dict[int, np.ndarray]


def capture_views(
    scan: SavedScan, rect: Rectification, X_FC: np.ndarray, params: StereoParams
) -> CaptureViews:
    """Stereo clouds of every readable capture; damaged captures are reported and skipped."""
    centre = np.array(scan.config.scan_center_m, float)
    radius = keep_out_radius_m(scan.config.cell)
    out = CaptureViews([], [], {})
    for index in scan.store.captured_indices():
        try:
            capture = scan.store.read_capture(index)
        except ScannerError as e:
            log.warning("capture %d skipped: %s", index, e)
            out.skipped.append({"index": index, "reason": str(e)})
            continue
        if capture.left.shape[1::-1] != rect.image_size:
            reason = f"image size {capture.left.shape[1::-1]} differs from the camera model's"
            out.skipped.append({"index": index, "reason": reason})
            continue
        X_WC = capture.X_WF @ X_FC
        cloud = view_cloud(rect, capture.left, capture.right, X_WC, centre, radius, params)
        depth = depth_image(rect, cloud)
        out.views.append(ViewCloud(index, cloud.points_C, cloud.colors, capture.X_WF, depth))
        out.joints[index] = capture.q_rad
    return out


def _truth(scan_dir: Path):
    """(the simulator's Truth record, the true surface in W), or None without truth.yaml."""
    path = scan_dir / "truth.yaml"
    if not path.is_file():
        return None
    import open3d as o3d

    from robots.truth import load_truth

    truth, raw = load_truth(path)
    mesh = o3d.io.read_triangle_mesh(str(scan_dir / raw.get("mesh", "truth_mesh.ply")))
    if len(mesh.triangles) == 0:
        raise ScannerError(f"{scan_dir}: truth mesh missing or empty")
    surface = TriangleSurface(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    return truth, surface


def _true_camera_centres(truth, joints: dict) -> list[np.ndarray]:
    from robots.kinematics import Kinematics

    kin = Kinematics()
    return [(kin.X_WF(q + truth.joint_offsets_rad) @ truth.X_FC)[:3, 3] for q in joints.values()]


def _geometry_filter(
    config: ScanConfig, X_FC: np.ndarray, stereo: StereoCamera, joints: dict, margin_m: float
):
    from robots.point_filter import make_geometry_filter
    from robots.workcell import build_workcell

    keep = make_geometry_filter(build_workcell(config.cell, None, X_FC, stereo.X_CR), margin_m)
    return lambda points_W, index: keep(points_W, joints[index])


def evaluate(result: ReconstructionResult, truth, surface, centres, samples: int) -> dict:
    """Metrics of every surface against the truth, and the hand-eye error before/after."""
    out: dict = {"surfaces": {}}
    results = {name: TriangleSurface(m.vertices, m.triangles) for name, m in result.meshes.items()}
    for name, mesh in results.items():
        out["surfaces"][name] = evaluate_surface(
            None, surface, result_mesh=mesh, camera_centres_W=centres, n_samples=samples
        )
    out["surfaces"]["fused_cloud"] = evaluate_surface(
        result.fused.points_W, surface, camera_centres_W=centres, n_samples=samples
    )
    before = handeye_error(result.X_FC_nominal, truth.X_FC)
    after = handeye_error(result.X_FC, truth.X_FC)
    out.update(after)
    out["handeye_error_before_mm"] = before["handeye_error_mm"]
    out["handeye_error_before_deg"] = before["handeye_error_deg"]
    return out


RECONSTRUCTION_MARKER = "reconstruction.yaml"


def holds_reconstruction(results_dir: Path) -> bool:
    return holds_result(results_dir, RECONSTRUCTION_MARKER)


def free_reconstruction_dir(scan_dir: Path) -> Path:
    """SCAN_DIR/results while it holds no reconstruction, else the first free SCAN_DIR/results-N:
    an offline run never replaces an earlier one (e.g. the scan's own, or a --no-icp run)."""
    return free_results_dir(scan_dir, RECONSTRUCTION_MARKER)


def _with_roi_centre(config: ReconstructionConfig, centre: np.ndarray) -> ReconstructionConfig:
    """The region of interest around the scan centre unless the configuration placed it."""
    if config.filter.roi.center_m is not None:
        return config
    roi = replace(config.filter.roi, center_m=tuple(float(c) for c in centre))
    return replace(config, filter=replace(config.filter, roi=roi))


def _metrics(result, truth, joints: dict, processing: ProcessingConfig) -> dict:
    """The report's accuracy keys: the primary surface's metrics first, then all of them."""
    centres = _true_camera_centres(truth[0], joints)
    metrics = evaluate(result, truth[0], truth[1], centres, processing.metric_samples)
    primary = metrics["surfaces"].get(processing.primary_surface)
    if primary is None:
        raise ScannerError(
            f"processing.primary_surface: '{processing.primary_surface}' was not built "
            f"(built: {', '.join(metrics['surfaces'])})"
        )
    return {**primary, "primary_surface": processing.primary_surface, **metrics}


def _write_results(result, processing: ProcessingConfig, truth, out: Path) -> dict:
    """Meshes, the fused cloud, reconstruction.yaml and the plots; their report keys."""
    from scanner.report import write_plots

    paths = save_outputs(result, out, processing.mesh_formats)
    details = summary(result)
    atomic_write_text(
        out / "reconstruction.yaml",
        yaml.safe_dump({"processing": to_dict(processing), **details}, sort_keys=False),
    )
    return {
        "X_FC_estimate": result.X_FC.tolist(),
        "X_FC_change_mm": 1e3 * details["X_FC_change_translation_m"],
        "X_FC_change_deg": math.degrees(details["X_FC_change_rotation_rad"]),
        "outputs": {k: str(p.relative_to(out)) for k, p in paths.items()},
        "plots": write_plots(result, out, truth[1] if truth else None, processing.primary_surface),
    }


def run_reconstruct(
    scan: Path | SavedScan,
    processing: ProcessingConfig | None = None,
    results_dir: Path | None = None,
    X_FC: np.ndarray | None = None,
    stereo: StereoCamera | None = None,
) -> ReconstructRun:
    """Reconstruct a saved scan (a directory, or one already opened). Defaults: the scan's own
    processing settings, camera model and X_FC (from its manifest); results in SCAN_DIR/results."""
    t0 = time.perf_counter()
    scan = scan if isinstance(scan, SavedScan) else open_scan(scan)
    processing = processing or scan.config.processing
    stereo = stereo or scan.stereo
    X_FC = scan.X_FC_nominal if X_FC is None else X_FC
    config = _with_roi_centre(processing.reconstruction, np.array(scan.config.scan_center_m))
    timer = StageTimer()

    with timer("stereo"):
        captured = capture_views(scan, compute_rectification(stereo), X_FC, processing.stereo)
    if len(captured.views) < config.min_views:
        raise ScannerError(
            f"{scan.root}: {len(captured.views)} usable captures, the reconstruction needs at "
            f"least {config.min_views}"
        )
    remove = _geometry_filter(
        scan.config, X_FC, stereo, captured.joints, processing.remove_margin_m
    )
    with timer("reconstruct"):
        result = reconstruct_views(captured.views, X_FC, config, remove)

    report: dict = {"captures_used": len(captured.views), "captures_skipped": captured.skipped}
    truth = _truth(scan.root)
    if truth is not None:
        with timer("evaluate"):
            report.update(_metrics(result, truth, captured.joints, processing))
    out = Path(results_dir) if results_dir else scan.store.results_dir
    earlier = _earlier_report(out)
    with staged_folder(out) as staging:
        with timer("write"):
            report.update(_write_results(result, processing, truth, staging))
        report["reconstruction_stage_s"] = {**timer.seconds, **result.timings_s}
        report["reconstruct_s"] = time.perf_counter() - t0
        merged = {**earlier, **report}
        _write_report(staging, merged)
    return ReconstructRun(result, merged, out)


def _earlier_report(out: Path) -> dict:
    """The scan's own report when `out` holds one but no reconstruction (the end of a scan);
    a reconstruction's report is replaced as a whole (the caller allowed it)."""
    path = out / "report.json"
    if holds_reconstruction(out) or not path.is_file():
        return {}
    return json.loads(path.read_text())


def _write_report(folder: Path, report: dict) -> None:
    from scanner.report import write_summary

    atomic_write_text(folder / "report.json", json.dumps(report, indent=2) + "\n")
    write_summary(report, folder)


def load_processing_config(path: Path) -> ProcessingConfig:
    return load_yaml_file(ProcessingConfig, path)

"""`scanner reconstruct SCAN_DIR` (and the end of `scanner scan`): captures -> measured model.

Stages, each timed in the report, reading the scan directory and writing only under the
results folder (captures are never modified):

    stereo      every capture: rectify, SGBM over the object's depth window, cloud in C
    reconstruct filter, remove robot/cell points (Drake geometry at the recorded joints),
                ICP + pose graph, hand-eye correction, fused cloud, Poisson / TSDF meshes
    evaluate    when truth.yaml is present: surface metrics and hand-eye error vs the truth
    write       fused_cloud.ply, mesh_*.ply (+ .obj/.stl on request), reconstruction.yaml,
                report.json (merged with the scan's), summary.md, plots
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from reconstruction.camera_model import stereo_camera_from_dict
from reconstruction.errors import ScannerError
from reconstruction.metrics import TriangleSurface, evaluate_surface, handeye_error
from reconstruction.pipeline import (
    ReconstructionConfig,
    ReconstructionResult,
    reconstruct_views,
    save_outputs,
    summary,
)
from reconstruction.rectification import Rectification, compute_rectification
from reconstruction.stereo import stereo_cloud
from reconstruction.stereo_params import StereoParams, object_depth_window
from reconstruction.views import DepthImage, ViewCloud
from scanner.captures import CaptureStore, atomic_write_text
from scanner.typed_yaml import load_yaml_file, to_dict

log = logging.getLogger("scanner.reconstruct")
MESH_FORMATS = (".ply", ".obj", ".stl")


@dataclass(frozen=True)
class ProcessingConfig:
    """How captures become a model (`processing:` in a scan config, or `--config` offline)."""

    stereo: StereoParams = field(default_factory=StereoParams)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    # Points closer than this to the robot, tool, rod or cell primitives are removed.
    remove_margin_m: float = 0.01
    # The surface whose metrics are the report's headline keys.
    primary_surface: str = "poisson"
    mesh_formats: tuple[str, ...] = (".ply",)
    # Surface samples for the metrics (area-uniform on the truth and on each result).
    metric_samples: int = 200_000

    def __post_init__(self) -> None:
        bad = [f for f in self.mesh_formats if f not in MESH_FORMATS]
        if bad:
            raise ScannerError(f"processing.mesh_formats: {bad} not in {', '.join(MESH_FORMATS)}")
        if not self.remove_margin_m >= 0:
            raise ScannerError("processing.remove_margin_m: must be >= 0")


@dataclass(frozen=True, eq=False)
class ReconstructRun:
    result: ReconstructionResult
    report: dict
    results_dir: Path


def _depth_view(rect: Rectification, cloud) -> DepthImage:
    """The cloud's rectified depth as an image on the rectified left grid (for TSDF)."""
    w, h = rect.image_size
    depth = np.zeros((h, w), np.float32)
    p_rect = cloud.points_C @ rect.R1.T
    u, v = cloud.pixels_rect[:, 0].astype(int), cloud.pixels_rect[:, 1].astype(int)
    depth[v, u] = p_rect[:, 2]
    X_CD = np.eye(4)
    X_CD[:3, :3] = rect.R1.T
    return DepthImage(depth, rect.P1[:3, :3], X_CD)


def _scan_centre(manifest: dict) -> np.ndarray:
    config = manifest["config"]
    return np.array(config["views"]["center_m"] or config["cell"]["object_center_m"], float)


def capture_views(
    store: CaptureStore, manifest: dict, rect: Rectification, X_FC: np.ndarray, params: StereoParams
) -> tuple[list[ViewCloud], list[dict], dict]:
    """Stereo clouds of every readable capture; damaged captures are reported and skipped."""
    centre = _scan_centre(manifest)
    radius = float(manifest["config"]["cell"]["object_size_m"]) * math.sqrt(3) / 2
    views, skipped, joints = [], [], {}
    for index in store.captured_indices():
        try:
            capture = store.read_capture(index)
        except ScannerError as e:
            log.warning("capture %d skipped: %s", index, e)
            skipped.append({"index": index, "reason": str(e)})
            continue
        if capture.left.shape[1::-1] != rect.image_size:
            reason = f"image size {capture.left.shape[1::-1]} differs from the camera model's"
            skipped.append({"index": index, "reason": reason})
            continue
        X_WC = capture.X_WF @ X_FC
        distance = float(np.linalg.norm(centre - X_WC[:3, 3]))
        z_min, z_max = object_depth_window(distance, radius)
        cloud = stereo_cloud(rect, capture.left, capture.right, z_min, z_max, params)
        views.append(
            ViewCloud(index, cloud.points_C, cloud.colors, capture.X_WF, _depth_view(rect, cloud))
        )
        joints[index] = capture.q_rad
    return views, skipped, joints


def _truth(scan_dir: Path):
    """(true X_FC, true mesh surface, true camera centres function) or None without truth."""
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


def _geometry_filter(manifest: dict, X_FC: np.ndarray, stereo, joints: dict, margin_m: float):
    from robots.point_filter import make_geometry_filter
    from robots.workcell import build_workcell
    from scanner.config import scan_config_from_dict

    cell = scan_config_from_dict(manifest["config"], "scan.yaml:config").cell
    keep = make_geometry_filter(build_workcell(cell, None, X_FC, stereo.X_CR), margin_m)
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


def holds_reconstruction(results_dir: Path) -> bool:
    return (Path(results_dir) / "reconstruction.yaml").is_file()


def free_results_dir(scan_dir: Path) -> Path:
    """SCAN_DIR/results while it holds no reconstruction, else the first free SCAN_DIR/results-N:
    an offline run never replaces an earlier one (e.g. the scan's own, or a --no-icp run)."""
    candidate, n = Path(scan_dir) / "results", 1
    while holds_reconstruction(candidate):
        n += 1
        candidate = Path(scan_dir) / f"results-{n}"
    return candidate


def run_reconstruct(
    scan_dir: Path,
    processing: ProcessingConfig | None = None,
    results_dir: Path | None = None,
    X_FC: np.ndarray | None = None,
    stereo=None,
) -> ReconstructRun:
    """Reconstruct a saved scan. Defaults: the scan's own processing settings, camera model and
    X_FC (from its manifest); results in SCAN_DIR/results."""
    t0 = time.perf_counter()
    stage_s: dict[str, float] = {}
    store = CaptureStore.open(scan_dir)
    manifest = store.read_manifest()
    if "config" not in manifest or "viewpoints" not in manifest:
        raise ScannerError(f"{store.manifest_path}: not a scan manifest (no config/viewpoints)")
    if processing is None:
        from scanner.config import scan_config_from_dict

        processing = scan_config_from_dict(manifest["config"], "scan.yaml:config").processing
    stereo = stereo or stereo_camera_from_dict(manifest["camera"], f"{store.manifest_path}:camera")
    X_FC = np.array(manifest["X_FC_nominal"], float) if X_FC is None else X_FC
    config = processing.reconstruction
    centre = _scan_centre(manifest)
    if config.filter.roi.center_m is None:
        roi = replace(config.filter.roi, center_m=tuple(float(c) for c in centre))
        config = replace(config, filter=replace(config.filter, roi=roi))

    t = time.perf_counter()
    rect = compute_rectification(stereo)
    views, skipped, joints = capture_views(store, manifest, rect, X_FC, processing.stereo)
    stage_s["stereo"] = time.perf_counter() - t
    if len(views) < config.min_views:
        raise ScannerError(
            f"{scan_dir}: {len(views)} usable captures, the reconstruction needs at least "
            f"{config.min_views}"
        )
    remove = _geometry_filter(manifest, X_FC, stereo, joints, processing.remove_margin_m)
    t = time.perf_counter()
    result = reconstruct_views(views, X_FC, config, remove)
    stage_s["reconstruct"] = time.perf_counter() - t

    report: dict = {"captures_used": len(views), "captures_skipped": skipped}
    truth = _truth(Path(scan_dir))
    if truth is not None:
        t = time.perf_counter()
        centres = _true_camera_centres(truth[0], joints)
        metrics = evaluate(result, truth[0], truth[1], centres, processing.metric_samples)
        primary = metrics["surfaces"].get(processing.primary_surface)
        if primary is None:
            raise ScannerError(
                f"processing.primary_surface: '{processing.primary_surface}' was not built "
                f"(built: {', '.join(metrics['surfaces'])})"
            )
        report.update(primary)
        report["primary_surface"] = processing.primary_surface
        report.update(metrics)
        stage_s["evaluate"] = time.perf_counter() - t

    t = time.perf_counter()
    out = Path(results_dir) if results_dir else store.results_dir
    paths = save_outputs(result, out, processing.mesh_formats)
    details = summary(result)
    atomic_write_text(
        out / "reconstruction.yaml",
        yaml.safe_dump({"processing": to_dict(processing), **details}, sort_keys=False),
    )
    report["X_FC_estimate"] = result.X_FC.tolist()
    report["X_FC_change_mm"] = 1e3 * details["X_FC_change_translation_m"]
    report["X_FC_change_deg"] = math.degrees(details["X_FC_change_rotation_rad"])
    report["outputs"] = {k: str(p.relative_to(out)) for k, p in paths.items()}
    report["reconstruction_stage_s"] = {**stage_s, **result.timings_s}
    from scanner.report import write_plots, write_summary

    report["plots"] = write_plots(
        result, report, out, truth[1] if truth else None, processing.primary_surface
    )
    stage_s["write"] = time.perf_counter() - t
    report["reconstruct_s"] = time.perf_counter() - t0
    merged = {}
    if (out / "report.json").is_file():
        merged = json.loads((out / "report.json").read_text())
    merged.update(report)
    atomic_write_text(out / "report.json", json.dumps(merged, indent=2) + "\n")
    write_summary(merged, out)
    return ReconstructRun(result, merged, out)


def load_processing_config(path: Path) -> ProcessingConfig:
    return load_yaml_file(ProcessingConfig, path)

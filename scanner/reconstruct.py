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
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from reconstruction.camera_model import StereoCamera
from reconstruction.coverage import coverage_estimate
from reconstruction.errors import ScannerError
from reconstruction.metrics import TriangleSurface, evaluate_surface, handeye_error
from reconstruction.outputs import save_outputs, summary
from reconstruction.pass_alignment import alignment_error
from reconstruction.pipeline import (
    ReconstructionConfig,
    ReconstructionResult,
    filter_views,
    reconstruct_views,
)
from reconstruction.stage_timer import StageTimer
from reconstruction.stereo.cloud import depth_image, view_cloud
from reconstruction.stereo.params import StereoParams
from reconstruction.stereo.rectification import Rectification, compute_rectification
from reconstruction.surfaces import FusedCloud, fuse_clouds
from reconstruction.transforms import invert, transform_points
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
    scan: SavedScan,
    rect: Rectification,
    X_FC: np.ndarray,
    params: StereoParams,
    indices: Sequence[int] | None = None,
) -> CaptureViews:
    """Stereo clouds of every readable capture (or of those among `indices`); damaged
    captures are reported and skipped."""
    centre = np.array(scan.config.scan_center_m, float)
    radius = keep_out_radius_m(scan.config.cell)
    out = CaptureViews([], [], {})
    wanted = None if indices is None else set(indices)
    for index in scan.store.captured_indices():
        if wanted is not None and index not in wanted:
            continue
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
    return truth, surface, raw


def _true_camera_centres(views: Gathered, to_first: dict[int, np.ndarray]) -> list:
    """True camera centres of every view, in the first hanging's frame (`to_first`: capture
    index -> the true transform of its hanging's placement onto the first's)."""
    from robots.kinematics import Kinematics

    kin = Kinematics()
    centres = []
    for i, q in views.joints.items():
        truth = views.truths[views.scan_of[i]][0]
        X_WC = kin.X_WF(q + truth.joint_offsets_rad) @ truth.X_FC
        centres.append(transform_points(to_first[i], X_WC[:3, 3][None])[0])
    return centres


def _object_poses(truth) -> list[np.ndarray]:
    """The object's true pose in each hanging of one scan."""
    raw = truth[2]
    return [np.array(X, float) for X in raw.get("X_WO_hangings", [truth[0].X_WO])]


def _to_first_hanging(views: Gathered) -> list[np.ndarray] | None:
    """Per hanging (over all scans), the true transform of its placement onto the first
    scan's first hanging; None without truth for every scan."""
    if any(t is None for t in views.truths):
        return None
    poses = [X for t in views.truths for X in _object_poses(t)]
    if len(poses) != len(views.hangings):
        return None
    return [poses[0] @ invert(X) for X in poses]


def _alignment_report(result, to_first, surface, hangings: int) -> dict:
    """Per hanging its views and alignment figures, and (with truth) the alignment errors."""
    passes = []
    for h in range(hangings):
        views = [v.index for v in result.views if v.hanging == h]
        record: dict = {"hanging": h + 1, "views": len(views)}
        a = next((a for a in result.alignments if a.hanging == h), None)
        if a is not None:
            record.update(
                overlap=a.overlap,
                inlier_rms_mm=1e3 * a.inlier_rms_m,
                free_space_violation=a.free_space_violation,
                ambiguity=a.ambiguity,
                verified=a.verified,
            )
            if surface is not None:
                points_h = transform_points(invert(to_first[h]), surface.vertices)
                dt, dr = alignment_error(a.T, to_first[h], points_h)
                record.update(alignment_error_mm=1e3 * dt, alignment_error_deg=math.degrees(dr))
        passes.append(record)
    out: dict = {"hangings": passes}
    errors = [p for p in passes if "alignment_error_mm" in p]
    if errors:
        out["alignment_error_mm"] = max(p["alignment_error_mm"] for p in errors)
        out["alignment_error_deg"] = max(p["alignment_error_deg"] for p in errors)
    return out


def geometry_filter(
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


def _metrics(result, views: Gathered, processing: ProcessingConfig, to_first) -> dict:
    """The report's accuracy keys (against the first scan's truth, in its first hanging's
    frame): the primary surface's metrics first, then all of them."""
    hanging_of = {i: h for h, indices in enumerate(views.hangings) for i in indices}
    centres = _true_camera_centres(views, {i: to_first[hanging_of[i]] for i in views.joints})
    truth = views.truths[0]
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


# Capture indices of the k-th scan of a merge are offset by k * INDEX_STRIDE.
INDEX_STRIDE = 100_000


@dataclass(frozen=True, eq=False)
class Gathered:
    """The views of one or more scans, ready for `reconstruct_views`: indices made unique
    across scans, the passes (hangings) of all of them, and per view its scan."""

    views: list[ViewCloud]
    skipped: list[dict]
    joints: dict[int, np.ndarray]
    hangings: list[list[int]]
    scan_of: dict[int, int]
    truths: list  # per scan: (Truth, true surface, truth file) or None
    remove: object  # remove_points(points_W, index) for all scans


def gather_views(
    scans: list[SavedScan],
    processing: ProcessingConfig,
    X_FC: np.ndarray | None = None,
    stereo: StereoCamera | None = None,
) -> Gathered:
    """Stereo clouds of every capture of every scan (each with its own camera model and X_FC
    unless given), with the point filter of each scan's cell."""
    out = Gathered([], [], {}, [], {}, [], None)
    filters = []
    for k, scan in enumerate(scans):
        camera = stereo or scan.stereo
        X = scan.X_FC_nominal if X_FC is None else X_FC
        captured = capture_views(scan, compute_rectification(camera), X, processing.stereo)
        offset = k * INDEX_STRIDE
        out.views.extend(replace(v, index=v.index + offset) for v in captured.views)
        out.skipped.extend({**d, "index": d["index"] + offset} for d in captured.skipped)
        out.joints.update({i + offset: q for i, q in captured.joints.items()})
        out.hangings.extend([i + offset for i in h] for h in scan.hangings)
        out.scan_of.update({v.index + offset: k for v in captured.views})
        out.truths.append(_truth(scan.root))
        filters.append(
            geometry_filter(scan.config, X, camera, captured.joints, processing.remove_margin_m)
        )
    remove = lambda points_W, index: filters[index // INDEX_STRIDE](  # noqa: E731
        points_W, index % INDEX_STRIDE
    )
    return replace(out, remove=remove)


def run_reconstruct(
    scan: Path | SavedScan,
    processing: ProcessingConfig | None = None,
    results_dir: Path | None = None,
    X_FC: np.ndarray | None = None,
    stereo: StereoCamera | None = None,
) -> ReconstructRun:
    """Reconstruct a saved scan (a directory, or one already opened). Defaults: the scan's own
    processing settings, camera model and X_FC (from its manifest); results in SCAN_DIR/results."""
    scan = scan if isinstance(scan, SavedScan) else open_scan(scan)
    out = Path(results_dir) if results_dir else scan.store.results_dir
    return reconstruct_scans([scan], out, processing, X_FC, stereo)


def reconstruct_scans(
    scans: list[SavedScan],
    out: Path,
    processing: ProcessingConfig | None = None,
    X_FC: np.ndarray | None = None,
    stereo: StereoCamera | None = None,
) -> ReconstructRun:
    """One model from the captures of one or more scans: every hanging of every scan,
    aligned into the first one's frame (refused, with nothing written, when an alignment does
    not verify). Results are written to `out` as a whole, or not at all."""
    t0 = time.perf_counter()
    first = scans[0]
    processing = processing or first.config.processing
    config = _with_roi_centre(processing.reconstruction, np.array(first.config.scan_center_m))
    timer = StageTimer()

    with timer("stereo"):
        views = gather_views(scans, processing, X_FC, stereo)
    if len(views.views) < config.min_views:
        raise ScannerError(
            f"{first.root}: {len(views.views)} usable captures, the reconstruction needs at "
            f"least {config.min_views}"
        )
    X_FC = first.X_FC_nominal if X_FC is None else X_FC
    hangings = views.hangings if len(views.hangings) > 1 else None
    with timer("reconstruct"):
        result = reconstruct_views(views.views, X_FC, config, views.remove, hangings)

    report: dict = {"captures_used": len(views.views), "captures_skipped": views.skipped}
    with timer("coverage"):
        centres = [v.X_WC[:3, 3] for v in result.views]
        coverage = coverage_estimate(result.fused, centres)
        report["coverage_estimate"] = coverage.fraction
        report["unseen_area_m2"] = coverage.unseen_area_m2
    truth = views.truths[0]
    to_first = _to_first_hanging(views)
    if to_first is not None:
        with timer("evaluate"):
            report.update(_metrics(result, views, processing, to_first))
    if hangings:
        surface = truth[1] if to_first is not None else None
        report.update(_alignment_report(result, to_first, surface, len(views.hangings)))
    earlier = _earlier_report(out)
    with staged_folder(out) as staging:
        with timer("write"):
            report.update(_write_results(result, processing, truth, staging))
        report["reconstruction_stage_s"] = {**timer.seconds, **result.timings_s}
        report["reconstruct_s"] = time.perf_counter() - t0
        merged = {**earlier, **report}
        _write_report(staging, merged)
    return ReconstructRun(result, merged, out)


def model_so_far(
    scan: SavedScan, indices: Sequence[int], X_FC: np.ndarray, stereo: StereoCamera
) -> tuple[FusedCloud, list[np.ndarray]]:
    """The fused cloud of some captures at their kinematic poses (no registration: a quick
    model to plan more views on), and their camera centres."""
    processing = scan.config.processing
    config = _with_roi_centre(processing.reconstruction, np.array(scan.config.scan_center_m))
    captured = capture_views(scan, compute_rectification(stereo), X_FC, processing.stereo, indices)
    remove = geometry_filter(scan.config, X_FC, stereo, captured.joints, processing.remove_margin_m)
    views, clouds, _ = filter_views(captured.views, X_FC, config, remove)
    X_WC = [v.X_WF @ X_FC for v in views]
    fused = fuse_clouds(clouds, X_WC, config.surfaces.fused_voxel_size_m)
    return fused, [X[:3, 3] for X in X_WC]


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

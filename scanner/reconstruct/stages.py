"""`scanner reconstruct SCAN_DIR` (and the end of `scanner scan`): captures -> measured model.

Stages, each timed in the report, reading the scan directory and writing only under the
results folder (captures are never modified):

    stereo      every capture: rectify, SGBM over the object's depth window, cloud in C
    reconstruct filter, remove robot/cell points (Drake geometry at the recorded joints),
                ICP + pose graph, hand-eye correction, fused cloud, Poisson / TSDF meshes
    evaluate    when truth.yaml is present: surface metrics and hand-eye error vs the truth
    write       fused_cloud.ply, mesh_*.ply (+ .obj/.stl on request), reconstruction.yaml,
                plots; then report.json (merged with the scan's) and summary.md
    (then)      model.html, the 3D page, once the results folder is in place
"""

from __future__ import annotations

import gc
import json
import logging
import math
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.stage_timer import StageTimer, cpu_seconds
from reconstruction.common.yaml_files import yaml_text
from reconstruction.outputs import export_files, save_outputs, summary
from reconstruction.pipeline import ReconstructionInputs, ReconstructionResult, reconstruct_views
from reconstruction.stereo.camera_model import StereoCamera
from reconstruction.surfaces.export import export_record, prepare_exports
from reconstruction.surfaces.topology import mesh_quality
from robots.sensors import sensor_named
from scanner.configs.scan import ProcessingConfig
from scanner.configs.typed_yaml import load_yaml_file, to_dict
from scanner.reconstruct.evaluation import (
    hangings_report,
    observed_samples,
    to_first_hanging,
    truth_metrics,
)
from scanner.reconstruct.model_scene import reconstruction_scene, write_reconstruction_page
from scanner.reconstruct.scan_views import gather_views, with_roi_centre
from scanner.reconstruct.view_stream import StreamedViews, settings_key
from scanner.reports.model_page import PAGE_NAME
from scanner.reports.self_checks import self_check_record
from scanner.scan_dir.captures import atomic_write_text
from scanner.scan_dir.known_turns import (
    known_turns,
    true_turntable_axis,
    turntable_report,
)
from scanner.scan_dir.manifest import SavedScan, open_scan
from scanner.scan_dir.outputs import RECONSTRUCTION_MARKER
from scanner.scan_dir.quick_alignments import quick_alignments
from scanner.scan_dir.results_folder import free_results_dir, holds_result, staged_folder

log = logging.getLogger("scanner.reconstruct.stages")


@dataclass(frozen=True)
class ModelWritten:
    """The results folder once the model's files were in it (before the pictures and the
    truth's metrics), and when: time.perf_counter() and the process's CPU seconds."""

    results_dir: Path
    model: Path  # the primary surface's mesh
    at_s: float
    cpu_s: float


@dataclass(frozen=True, eq=False)
class ReconstructRun:
    result: ReconstructionResult
    report: dict
    results_dir: Path
    # Builds the scene of the results' 3D page (`add_model_page`); None once it is written.
    page_scene: Callable[[], object] | None = None
    model_written: ModelWritten | None = None


def holds_reconstruction(results_dir: Path) -> bool:
    return holds_result(results_dir, RECONSTRUCTION_MARKER)


def free_reconstruction_dir(scan_dir: Path) -> Path:
    """SCAN_DIR/results while it holds no reconstruction, else the first free SCAN_DIR/results-N:
    an offline run never replaces an earlier one (e.g. the scan's own, or a --no-icp run)."""
    return free_results_dir(scan_dir, RECONSTRUCTION_MARKER)


def _write_pictures(result, processing: ProcessingConfig, truth, out: Path):
    """The plots and, with the truth, every surface's deviation picture and statistics."""
    from scanner.reports.plots import write_plots

    return write_plots(
        result,
        out,
        truth[1] if truth else None,
        processing.deviation_scale_m,
        processing.deviation_tolerance_m,
    )


def _write_model(
    result, processing: ProcessingConfig, out: Path, eyes: dict[int, np.ndarray]
) -> dict:
    """Meshes, the fused cloud and reconstruction.yaml, and their report keys. `eyes`: each
    view's camera centres at its final pose (kept with the view: what it saw)."""
    exports = prepare_exports(result.meshes, processing.mesh_export, processing.primary_surface)
    paths = save_outputs(result, out, processing.mesh_formats, exports)
    details = summary(result)
    for view in details["views"]:
        view["eye_centres_W_m"] = eyes[view["index"]].tolist()
    atomic_write_text(
        out / "reconstruction.yaml",
        yaml_text({"processing": to_dict(processing), **details}),
    )
    converged = {}
    if "handeye" in details:
        d = details["handeye"]["diagnosis"]
        converged = {
            "handeye_converged": d["converged"],
            "handeye_diagnosis": {
                "match_fraction": d["match_fraction"],
                "match_rms_mm": 1e3 * d["match_rms_m"],
                "axxb_disagreement_mm": 1e3 * d["axxb_disagreement_m"],
                "axxb_disagreement_deg": math.degrees(d["axxb_disagreement_rad"]),
                "last_change_mm": 1e3 * d["last_change_m"],
                "last_change_deg": math.degrees(d["last_change_rad"]),
                # The accuracy the correction states (RMS error of X_FC's origin and
                # orientation): what "converged" claims.
                "sigma_mm": 1e3 * d["sigma_translation_m"],
                "sigma_deg": math.degrees(d["sigma_rotation_rad"]),
                "failures": d["failures"],
            },
        }
    refinement = details.get("handeye", {}).get("refinement")
    if refinement is not None:
        converged["handeye_fit"] = {
            "rms_before_mm": 1e3 * refinement["rms_before_m"],
            "rms_after_mm": 1e3 * refinement["rms_after_m"],
        }
    return {
        **converged,
        "X_FC_estimate": result.X_FC.tolist(),
        "X_FC_change_mm": 1e3 * details["X_FC_change_translation_m"],
        "X_FC_change_deg": math.degrees(details["X_FC_change_rotation_rad"]),
        "outputs": {k: str(p.relative_to(out)) for k, p in paths.items()},
        "mesh_export": export_record(exports, export_files(exports, processing.mesh_formats)),
    }


def _settings(processing: ProcessingConfig, scan: SavedScan, origin: dict[str, str]) -> dict:
    """The options behind a result, for its summary (`origin`: where X_FC and the processing
    settings came from when the caller chose them)."""
    rec = processing.reconstruction
    calibration = scan.config.calibration_file
    scan_X_FC = (
        f"the scan's, from the calibration file {calibration}"
        if calibration
        else "the scan's nominal (design) X_FC, no calibration given"
    )
    return {
        "icp": rec.icp.enabled,
        "handeye_correction": rec.handeye.enabled,
        "surfaces": list(rec.surfaces.methods),
        "primary_surface": processing.primary_surface,
        "mesh_formats": list(processing.mesh_formats),
        "deviation_scale_mm": 1e3 * processing.deviation_scale_m,
        "deviation_tolerance_mm": 1e3 * processing.deviation_tolerance_m,
        "X_FC_given": origin.get("X_FC_given", scan_X_FC),
        "processing_from": origin.get("processing_from", "the scan's own settings"),
    }


# Capture indices of the k-th scan of a merge are offset by k * INDEX_STRIDE.


def run_reconstruct(
    scan: Path | SavedScan | list[SavedScan],
    processing: ProcessingConfig | None = None,
    results_dir: Path | None = None,
    X_FC: np.ndarray | None = None,
    stereo: StereoCamera | None = None,
    streamed: StreamedViews | None = None,
    progress: bool = False,
    origin: dict[str, str] | None = None,
    page: bool = True,
    on_model: Callable[[ModelWritten], None] | None = None,
) -> ReconstructRun:
    """Reconstruct a saved scan (a directory, or one already opened), or merge a list of opened
    scans into one model: every hanging of every scan aligned into the first one's frame. A
    scan's hanging whose alignment does not verify is left out of its model (the report says
    which and why; its self-check fails); a merge is refused then, with nothing written (the
    scans may be of different objects). Defaults: the (first)
    scan's own processing settings, camera model and X_FC (from its manifest); results in its
    SCAN_DIR/results, written as a whole or not at all.
    `streamed`: per-view results computed while the scan ran (used where the settings match);
    `progress`: show the stages on stderr (when it is a terminal); `origin`: where the caller's
    X_FC and processing came from, for the summary (`X_FC_given`, `processing_from`);
    `page`: write the 3D page once the results are in place (else the caller does, with
    `add_model_page`, e.g. after timing the reconstruction); `on_model`: told as soon as the
    model's files are in the results folder (the pictures and the truth's metrics follow)."""
    if isinstance(scan, list):
        scans = scan
    else:
        scans = [scan if isinstance(scan, SavedScan) else open_scan(scan)]
    out = Path(results_dir) if results_dir else scans[0].store.results_dir
    t0 = time.perf_counter()
    processing = processing or scans[0].config.processing
    display = _stage_display(scans) if progress else None
    try:
        run = _reconstruct(
            scans, out, processing, X_FC, stereo, streamed, display, t0, origin, on_model
        )
    finally:
        if display is not None:
            display.close()
    return add_model_page(run) if page else run


def add_model_page(run: ReconstructRun) -> ReconstructRun:
    """model.html in the finished results folder, and its link in report.json and summary.md.
    The model is complete and on disk before its page is drawn: the page is a view of it, not
    part of it, and a failure to write it is a warning."""
    if run.page_scene is None:
        return run
    out = run.results_dir
    seconds = write_reconstruction_page(out, run.page_scene)
    if seconds is None:
        return replace(run, page_scene=None)
    report = {**run.report, "model_page": PAGE_NAME, "model_page_s": seconds}
    try:
        _write_report(out, report)
    except OSError as e:
        log.warning("%s: the link to %s not added (%s)", out, PAGE_NAME, e)
        return replace(run, page_scene=None)
    return ReconstructRun(run.result, report, out, None, run.model_written)


def _stage_display(scans: list[SavedScan]):
    from scanner.reconstruct.progress import StageProgress

    return StageProgress(sum(len(s.store.captured_indices()) for s in scans))


def _reconstruct(
    scans, out, processing, X_FC, stereo, streamed, display, t0, origin, on_model
) -> ReconstructRun:
    first = scans[0]
    config = with_roi_centre(processing.reconstruction, np.array(first.config.scan_center_m))
    on_stage = display.on_stage if display else None
    timer = StageTimer(on_stage=on_stage)
    ready, filtered, arriving = _streamed_for(streamed, first, processing, X_FC, stereo)

    with timer("stereo"):
        views = gather_views(
            scans, processing, X_FC, stereo, ready, display.on_view if display else None
        )
    if len(views.views) < config.min_views:
        raise ScannerError(
            f"{first.root}: {len(views.views)} usable captures, the reconstruction needs at "
            f"least {config.min_views}"
        )
    X_FC = first.X_FC_nominal if X_FC is None else X_FC
    hangings = views.hangings if len(views.hangings) > 1 else None
    to_first = to_first_hanging(views)

    def eyes_of(index: int, X_WC: np.ndarray) -> np.ndarray:
        # A view saw what both of its cameras saw.
        return (stereo or scans[views.scan_of[index]].camera_model).eye_centres_W(X_WC)

    # Nothing of the evaluation runs beside the model's stages: it would take the cores the
    # Poisson solve and the hand-eye fit wait for.
    with timer("reconstruct"):
        inputs = ReconstructionInputs(
            views=views.views,
            X_FC_nominal=X_FC,
            config=config,
            remove_points=views.remove,
            hangings=hangings,
            filtered=filtered,
            eyes_of=eyes_of,
            fixtures=views.fixtures,
            supports=views.supports,
            arriving=arriving,
            leave_out_unaligned=len(scans) == 1,
            turns=known_turns(first) if hangings and len(scans) == 1 else None,
            earlier_alignments=quick_alignments(first) if hangings and len(scans) == 1 else None,
        )
        result = reconstruct_views(inputs, on_stage)

    report: dict = {
        "sensor": sensor_named(first.sensor).describe(stereo or first.camera_model),
        "captures_used": len(views.views),
        "captures_skipped": views.skipped,
        "pairs_registered_while_scanning": result.pairs_before,
        "settings": _settings(processing, first, origin or {}),
    }
    truth = views.truths[0]
    earlier = _earlier_report(out)
    # The scan's own report (and its summary) is read above and merged into the new one.
    with staged_folder(out, RECONSTRUCTION_MARKER, own=("report.json", "summary.md")) as staging:
        # The model first, as a whole: what the user waits for.
        eyes = {v.index: eyes_of(v.index, v.X_WC) for v in result.views}
        report["coverage_estimate"] = result.coverage.fraction
        report["unseen_area_m2"] = result.coverage.unseen_area_m2
        closed = result.meshes.get("poisson_closed")
        if closed is not None:
            quality = mesh_quality(closed)
            report["closed_model"] = {
                "watertight": quality.watertight,
                "filled_area_m2": closed.filled_area_m2,
                # The share of the closed surface no data hold (bridged over what no view saw).
                "interpolated_fraction": closed.filled_area_m2 / quality.area_m2
                if quality.area_m2 > 0
                else math.nan,
            }
        with timer("write"):
            report.update(_write_model(result, processing, staging, eyes))
            if hangings:
                report.update(hangings_report(result, views, None))
            if inputs.turns is not None:
                report["turntable"] = turntable_report(
                    inputs.turns, result.alignments, true_turntable_axis(first, views.truths[0])
                )
            report["reconstruction_stage_s"] = {**timer.seconds, **result.timings_s}
            report["reconstruct_s"] = time.perf_counter() - t0
            merged = {**earlier, **report}
            merged["self_checks"] = self_check_record(merged)
            _write_report(staging, merged)
    mesh = f"mesh_{processing.primary_surface}."
    primary = out / next((v for k, v in report["outputs"].items() if k.startswith(mesh)), "")
    written = ModelWritten(out, primary, time.perf_counter(), cpu_seconds())
    if on_model is not None:
        on_model(written)
    # Then what measures and shows it: the pictures (Drake's renderer, matplotlib) beside the
    # truth's metrics (Open3D, numpy), written into the results folder with the report again.
    truth_samples = None
    # Garbage of this thread is freed here, not by a collection the pictures' thread happens to
    # trigger: a dropped simulation's VTK renderer holds a GL context that may only be destroyed
    # where it was made (destroying it from another thread can abort the process).
    gc.collect()
    with ThreadPoolExecutor(max_workers=1) as beside:
        pictures = beside.submit(_write_pictures, result, processing, truth, out)
        if to_first is not None:
            with timer("evaluate"):
                # The truth's side (ray casting from every true view), then the surfaces on it.
                truth_samples = observed_samples(views, processing, to_first, result.left_out)
                report.update(truth_metrics(result, views, processing, to_first, truth_samples))
            if hangings:
                report.update(hangings_report(result, views, to_first))
        plots, deviation = pictures.result()
    report.update({"plots": plots, **({"deviation": deviation} if deviation else {})})
    report["reconstruction_stage_s"] = {**timer.seconds, **result.timings_s}
    report["model_written_s"] = written.at_s - t0
    report["reconstruct_s"] = time.perf_counter() - t0
    merged = {**earlier, **report}
    merged["self_checks"] = self_check_record(merged)
    _write_report(out, merged)

    def scene():
        model = stereo or first.camera_model
        return reconstruction_scene(result, views, processing, first, model, truth, truth_samples)

    return ReconstructRun(result, merged, out, scene, written)


def _streamed_for(streamed, scan: SavedScan, processing, X_FC, stereo) -> tuple[dict, dict, object]:
    """The streamed views, filtered clouds and registered pairs of `scan` when they were made
    with the settings of this run, else nothing (they are then computed again)."""
    if streamed is None:
        return {}, {}, None
    X = scan.X_FC_nominal if X_FC is None else X_FC
    if streamed.key != settings_key(scan, processing, X, stereo or scan.camera_model):
        log.info("per-view results of the scan were made with other settings: recomputed")
        return {}, {}, None
    ready = {i: (v.view, v.q_rad) for i, v in streamed.views.items()}
    filtered = {i: v.cloud for i, v in streamed.views.items() if v.cloud is not None}
    return ready, filtered, streamed.arriving


def _earlier_report(out: Path) -> dict:
    """The scan's own report when `out` holds one but no reconstruction (the end of a scan);
    a reconstruction's report is replaced as a whole (the caller allowed it)."""
    path = out / "report.json"
    if holds_reconstruction(out) or not path.is_file():
        return {}
    return json.loads(path.read_text())


def _write_report(folder: Path, report: dict) -> None:
    from scanner.reports.summary import write_summary

    atomic_write_text(folder / "report.json", json.dumps(report, indent=2) + "\n")
    write_summary(report, folder)


def load_processing_config(path: Path) -> ProcessingConfig:
    return load_yaml_file(ProcessingConfig, path)

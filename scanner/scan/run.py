"""`scanner scan`: set up the (simulated) cell, choose and order views, run the decision maker,
store every capture, then reconstruct and report."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.stage_timer import StageTimer, cpu_seconds
from robots.models.kinematics import Kinematics
from robots.simulation.cell import Simulation, object_vertices_W
from robots.simulation.operator import hung_pose
from robots.simulation.truth import hung_pose_of, save_truth
from scanner.configs.scan import ScanConfig, scan_config_to_dict
from scanner.monitor.scan_monitor import intruders_truth
from scanner.reconstruct.stages import add_model_page, holds_reconstruction, run_reconstruct
from scanner.reconstruct.view_stream import ViewStream, processing_hidden_s
from scanner.reports.summary import write_summary
from scanner.scan.decision import RunSummary
from scanner.scan.hangings import HangingRunner
from scanner.scan.layout import laid_out
from scanner.scan.rescan import record_left_out, reopen_left_out
from scanner.scan.session import interruptible, log_file, meshcat_if
from scanner.scan.viewpoints import ViewPlan, generate_viewpoints
from scanner.scan.world import ScanWorld, setup_world
from scanner.scan_dir.captures import CaptureStore, atomic_write_text, require_same_settings
from scanner.scan_dir.manifest import SavedScan, new_manifest, open_scan, require_robot_scan
from scanner.scan_dir.views import PlannedView

log = logging.getLogger("scanner.scan.run")


@dataclass
class ScanResult:
    scan_dir: Path
    report: dict


def _write_truth(store: CaptureStore, sim: Simulation, hangings: int, intruders: list) -> None:
    import open3d as o3d

    vertices_W = object_vertices_W(sim.object_mesh, sim.truth.X_WO)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices_W),
        o3d.utility.Vector3iVector(np.array(sim.object_mesh.triangles)),
    )
    o3d.io.write_triangle_mesh(str(store.root / ".truth_mesh.tmp.ply"), mesh)
    (store.root / ".truth_mesh.tmp.ply").rename(store.root / "truth_mesh.ply")
    # Every hanging's object pose (the simulator draws them from the seed; only the
    # evaluation reads them). The mesh is the object in the first hanging.
    X_WO_hangings = [
        hung_pose(sim.workcell.config.X_WO, sim.truth.seed, p).tolist() for p in range(hangings)
    ]
    if sim.workcell.presentation != "hanging":
        # Each further pass's pose is recorded when the turntable has turned the object.
        X_WO_hangings = [sim.truth.X_WO.tolist()]
    extra = {"mesh": "truth_mesh.ply", "X_WO_hangings": X_WO_hangings}
    if intruders:  # the cell monitor's simulated intruders (the software is never told)
        extra["intruders"] = intruders
    save_truth(sim.truth, store.root / "truth.yaml", extra)


def _open_resumed(resume: Path, requested: ScanConfig | None) -> SavedScan:
    """The interrupted scan, checked against the configuration asked for now (if any), with
    its partial capture (if the scan was killed mid-write) removed; a scan with a hanging left
    out of its model, reopened to scan that hanging again (`reopen_left_out`)."""
    saved = open_scan(resume)
    require_robot_scan(saved, "--resume")
    # A hanging that did not align was left out of the model: resuming scans it again.
    left_out = bool(saved.manifest.get("left_out_hangings"))
    if saved.manifest.get("status") == "complete" and not left_out:
        raise ScannerError(
            f"{resume}: the scan is complete; nothing was changed. To reconstruct it again "
            f"(into a new results-N/), run: scanner reconstruct {resume}"
        )
    if requested is not None:
        require_same_settings(
            resume, "scan", scan_config_to_dict(saved.config), scan_config_to_dict(requested)
        )
    removed = saved.store.remove_partial_captures()
    if removed:
        log.warning("removed interrupted partial captures: %s", ", ".join(removed))
    return reopen_left_out(saved) if left_out else saved


def new_scan_views(config: ScanConfig, world: ScanWorld) -> tuple[ViewPlan, list[PlannedView]]:
    """The viewpoints of a new scan, reached from where the arm stands, and the views of every
    hanging (`scanner scan --plan-only` plans the same ones)."""
    q_home = world.robot.joint_positions()
    plan = generate_viewpoints(
        config.views,
        config.scan_center_m,
        lambda vp: world.planner.reachable(vp, q_home),
        lambda q: world.planner.estimate_duration_s(q_home, q),
    )
    # The same viewpoints in every hanging (they look at the scan centre, where each hanging
    # puts the object's centre); views of pass p are numbered p * count + k.
    count = len(plan.views)
    views = [
        dataclasses.replace(v, index=p * count + v.index)
        for p in range(config.first_hangings)
        for v in plan.views
    ]
    return plan, views


def _start_new(
    config: ScanConfig, out_dir: Path | None, force: bool, world: ScanWorld
) -> tuple[CaptureStore, list[PlannedView], tuple[tuple[int, ...], ...]]:
    """Views around the scan centre, then the scan directory with its manifest (and truth);
    also which views belong to each hanging (view k of hanging p is number p * count + k)."""
    plan, views = new_scan_views(config, world)
    count = len(plan.views)
    hangings = tuple(
        tuple(p * count + v.index for v in plan.views) for p in range(config.first_hangings)
    )
    plan_info = {
        "reachable_fraction": plan.reachable_fraction,
        "dropped_views": [{"direction": d.direction, "reason": d.reason} for d in plan.dropped],
        "hangings": [list(h) for h in hangings],
        "reachable_directions": plan.reachable_directions.tolist(),
        "hanging": 0,
        "views_per_hanging": count,
    }
    manifest = new_manifest(config, world.camera_model, world.X_FC, views, plan_info)
    store = CaptureStore.create(out_dir, manifest, force)
    if world.sim is not None:
        intruders = intruders_truth(config.monitor) if config.monitor.enabled else []
        _write_truth(store, world.sim, config.first_hangings, intruders)
    return store, views, hangings


def _live_view(world: ScanWorld, meshcat) -> object | None:
    """Meshcat's view of the arm, its paths and the growing cloud (None without --meshcat)."""
    if meshcat is None:
        return None
    from robots.simulation.live_view import LiveView

    live = LiveView(world.shown_cell, meshcat, Kinematics(world.arm).X_WF)
    live.show(world.robot.joint_positions() + world.joint_offsets_rad)
    return live


def _scan_report(
    config: ScanConfig,
    store: CaptureStore,
    summary: RunSummary,
    tour_cost_s: float,
    total: int,
    timer: StageTimer,
    wall0: float,
) -> dict:
    manifest = store.read_manifest()
    skipped = manifest.get("skipped_views", [])
    return {
        "object": config.object,
        "status": manifest["status"],
        "views_planned": total,
        "views_captured": len(store.captured_indices()),
        "views_skipped": len(skipped),
        "skipped": skipped,
        "views_dropped_unreachable": len(manifest.get("dropped_views", [])),
        "reachable_fraction": manifest.get("reachable_fraction"),
        "hangings_asked": config.hangings,
        "hanging_decisions": manifest.get("hanging_log", []),
        "stop_reason": manifest.get("stop_reason"),
        "robot_motion_s": summary.robot_motion_s,
        "estimated_tour_s": tour_cost_s,
        "wall_s": time.perf_counter() - wall0,
        "stage_s": {
            **timer.seconds,
            **{f"capture.{k}": v for k, v in summary.stage_s.items()},
        },
    }


def run_scan(
    config: ScanConfig | None,
    out_dir: Path | None,
    resume: Path | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    meshcat: bool = False,
    show_stages: bool = False,
    on_model: Callable[[Path], None] | None = None,
) -> ScanResult:
    """A new scan into `out_dir`, or continue the scan in `resume`.

    Args:
        config: the whole scan configuration (None: the defaults, or the saved one on resume;
            given with `resume`, it must equal the saved one).
        out_dir: the scan directory to create (None: `scans/OBJECT-TIMESTAMP`).
        resume: an interrupted scan to continue: its missing views are captured; a scan whose
            captures are complete is only reconstructed; a scan with a hanging left out of its
            model scans that hanging again (its captures and results moved aside, kept); any
            other complete scan is refused (nothing is changed).
        force: replace an existing scan directory at `out_dir`.
        progress: `progress(captured, total)` after each view.
        meshcat: show the arm, its paths and the growing cloud in Meshcat.
        show_stages: the reconstruction's stages on stderr (when it is a terminal).
        on_model: `on_model(path)` as soon as the model's mesh is written (its pictures and
            measurements follow).

    Returns:
        The scan directory and its report (`results/report.json`: the scan's and, when it
        reconstructed, the reconstruction's figures).

    Raises:
        ScannerError: bad configuration or files (exit 2); the arm is never moved then.
        StorageError: a write failed; every capture so far is kept and the scan resumable."""
    saved = _open_resumed(resume, config) if resume is not None else None
    if saved is not None and saved.manifest.get("status") == "captured":
        return _reconstruct_captured(saved, show_stages)
    timer = StageTimer()
    wall0 = time.perf_counter()
    # A new scan's object hangs where its configuration says, or where its arm sees most of it.
    config = saved.config if saved else laid_out(config or ScanConfig())
    hanging = saved.hanging if saved else 0  # where the object hangs now
    again = saved.manifest.get("rescanning") if saved else None
    first = hanging if again is None else again
    with timer("setup"):
        viewer = meshcat_if(meshcat)
        X_WO = hung_pose_of(saved.root / "truth.yaml", hanging) if saved else None
        world = setup_world(config, viewer, hanging, X_WO)
        live = _live_view(world, viewer)
    if saved is None:
        with timer("viewpoints"):
            store, views, hangings = _start_new(config, out_dir, force, world)
    else:
        store, views, hangings = saved.store, list(saved.views), saved.hangings
        store.update_manifest(status="running")
    # Per-view work runs beside the capture loop when the scan reconstructs at its end.
    stream = ViewStream(saved or open_scan(store.root)) if config.reconstruct else None
    if stream is not None and saved is not None:
        stream.submit_stored()
    run = HangingRunner(config, world, store, views, live, viewer, timer, progress, stream)
    with interruptible(run), log_file(store.root / "scan.log"):
        try:
            summary = run.passes(hangings, first)
        finally:
            # From the last capture stored on, the user waits for the model: what ran after it
            # inside the passes (the decision about another hanging) counts.
            last_capture_wall, last_capture_cpu = run.last_capture or (
                time.perf_counter(),
                cpu_seconds(),
            )
            streamed = stream.finish() if stream else None
    status = "interrupted" if summary.state.value == "aborted" else "captured"
    skipped = [{"index": o.index, "reason": o.reason} for o in summary.skipped]
    store.update_manifest(status=status, skipped_views=skipped)

    def report() -> dict:
        out = _scan_report(config, store, summary, run.tour_cost_s, len(views), timer, wall0)
        if run.monitor is not None:
            out["monitor"] = run.monitor.report()
        presented = run.presentation.report(store.read_manifest())
        if presented is not None:
            out["presentation"] = presented
        if streamed is not None:
            seconds = streamed.processing_s()
            out["processing_s"] = sum(seconds.values())
            out["processing_hidden_s"] = processing_hidden_s(summary.outcomes, seconds)
        return out

    _write_scan_report(store, report())
    if config.reconstruct and status == "captured":
        with timer("reconstruction"):
            done = run_reconstruct(
                saved or open_scan(store.root),
                streamed=streamed,
                progress=show_stages,
                page=False,
                on_model=(lambda written: on_model(written.model)) if on_model else None,
            )
        written = done.model_written
        waited = {
            # To the model's files: its pictures and measurements come after.
            "after_last_capture_s": written.at_s - last_capture_wall,
            "after_last_capture_cpu_s": written.cpu_s - last_capture_cpu,
            "last_capture_to_results_s": time.perf_counter() - last_capture_wall,
        }
        # The 3D page after the model: its time is not the wait for the model.
        add_model_page(done)
        record_left_out(store, done.report)
        store.update_manifest(status="complete")
        _write_scan_report(store, {**report(), **waited})
    return ScanResult(store.root, _read_report(store))


def _read_report(store: CaptureStore) -> dict:
    return json.loads((store.results_dir / "report.json").read_text())


def _write_scan_report(store: CaptureStore, report: dict) -> None:
    """The scan's keys into results/report.json, keeping the reconstruction's keys there."""
    path = store.results_dir / "report.json"
    store.results_dir.mkdir(exist_ok=True)
    merged = {**json.loads(path.read_text()), **report} if path.is_file() else report
    atomic_write_text(path, json.dumps(merged, indent=2) + "\n")
    if "reconstruct_s" in merged:
        write_summary(merged, store.results_dir)


def _reconstruct_captured(saved: SavedScan, show_stages: bool) -> ScanResult:
    """A scan whose captures are all there but whose reconstruction did not finish (or was
    not asked for): reconstruct into results/ (kept from an earlier run if complete)."""
    store = saved.store
    if not holds_reconstruction(store.results_dir):
        if not saved.config.reconstruct:
            raise ScannerError(
                f"{saved.root}: every view is captured and the configuration does not "
                f"reconstruct; nothing was changed. Reconstruct with: scanner reconstruct "
                f"{saved.root}"
            )
        run_reconstruct(saved, progress=show_stages)
    record_left_out(store, _read_report(store))
    store.update_manifest(status="complete")
    _write_scan_report(store, {"status": "complete"})
    return ScanResult(store.root, _read_report(store))

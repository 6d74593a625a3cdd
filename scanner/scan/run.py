"""`scanner scan`: set up the (simulated) cell, choose and order views, run the decision maker,
store every capture, then reconstruct and report."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planners.tour import Tour, plan_tour
from reconstruction.common.errors import ScannerError, StorageError
from reconstruction.common.stage_timer import StageTimer
from robots.models.kinematics import Kinematics
from robots.simulation.cell import Simulation, object_vertices_W
from robots.simulation.operator import hung_pose
from robots.simulation.truth import save_truth
from scanner.monitor.cell_monitor import MonitorStoppedError
from scanner.monitor.scan_monitor import ScanMonitor, intruders_truth
from scanner.reconstruct.scan_views import model_so_far
from scanner.reconstruct.stages import holds_reconstruction, run_reconstruct
from scanner.reports.summary import write_summary
from scanner.scan.captures import CaptureStore, atomic_write_text, require_same_settings
from scanner.scan.config import ScanConfig, scan_config_to_dict
from scanner.scan.decision import DecisionMaker, FixedViewList, RunSummary
from scanner.scan.manifest import SavedScan, new_manifest, open_scan, views_to_manifest
from scanner.scan.next_best_view import CoverageModel
from scanner.scan.session import interruptible, log_file, meshcat_if
from scanner.scan.view_stream import ViewStream, processing_hidden_s, with_stream
from scanner.scan.viewpoints import PlannedView, ViewPlan, generate_viewpoints, planned_view
from scanner.scan.world import ScanWorld, WatchedRobot, live_cloud, setup_world

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
    extra = {"mesh": "truth_mesh.ply", "X_WO_hangings": X_WO_hangings}
    if intruders:  # the cell monitor's simulated intruders (the software is never told)
        extra["intruders"] = intruders
    save_truth(sim.truth, store.root / "truth.yaml", extra)


def _open_resumed(resume: Path, requested: ScanConfig | None) -> SavedScan:
    """The interrupted scan, checked against the configuration asked for now (if any), with
    its partial capture (if the scan was killed mid-write) removed."""
    saved = open_scan(resume)
    if saved.manifest.get("status") == "complete":
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
    return saved


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
        for p in range(config.hangings)
        for v in plan.views
    ]
    return plan, views


def _start_new(
    config: ScanConfig, out_dir: Path | None, force: bool, world: ScanWorld
) -> tuple[CaptureStore, list[PlannedView]]:
    """Views around the scan centre, then the scan directory with its manifest (and truth)."""
    plan, views = new_scan_views(config, world)
    count = len(plan.views)
    plan_info = {
        "reachable_fraction": plan.reachable_fraction,
        "dropped_views": [{"direction": d.direction, "reason": d.reason} for d in plan.dropped],
        "hangings": [[p * count + v.index for v in plan.views] for p in range(config.hangings)],
        "reachable_directions": plan.reachable_directions.tolist(),
        "hanging": 0,
    }
    manifest = new_manifest(config, world.stereo, world.X_FC, views, plan_info)
    store = CaptureStore.create(out_dir, manifest, force)
    if world.sim is not None:
        intruders = intruders_truth(config.monitor) if config.monitor.enabled else []
        _write_truth(store, world.sim, config.hangings, intruders)
    return store, views


def _live_view(world: ScanWorld, meshcat) -> object | None:
    """Meshcat's view of the arm, its paths and the growing cloud (None without --meshcat)."""
    if meshcat is None:
        return None
    from robots.simulation.live_view import LiveView

    live = LiveView(world.shown_cell, meshcat, Kinematics().X_WF)
    live.show(world.robot.joint_positions() + world.joint_offsets_rad)
    return live


def _decision_maker(
    config: ScanConfig,
    world: ScanWorld,
    store: CaptureStore,
    views: list[PlannedView],
    todo: list[PlannedView],
    tour: Tour,
    live,
    stream: ViewStream | None = None,
    monitor: ScanMonitor | None = None,
) -> DecisionMaker:
    ordered = [todo[k] for k in tour.order]
    preferred = {todo[k].index: tour.option[k] for k in range(len(todo))}
    robot = WatchedRobot(world.robot, live, world.joint_offsets_rad) if live else world.robot
    camera = world.camera
    if monitor is not None:
        robot, camera = monitor.drivers(robot, camera, world.planner.plan)
    return DecisionMaker(
        world.planner,
        robot,
        camera,
        store,
        FixedViewList(ordered, preferred),
        len(views),
        Kinematics().X_WF,
        config.machine,
        process=with_stream(
            live_cloud(live, config, world.stereo, world.X_FC) if live else None, stream
        ),
    )


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
) -> ScanResult:
    """A new scan into `out_dir`, or continue the scan in `resume` (then `config` must be None
    or equal to the saved one). A resumed scan whose captures are complete is only
    reconstructed; a complete scan is refused (nothing is changed). `show_stages`: the
    reconstruction's stages on stderr (when it is a terminal)."""
    saved = _open_resumed(resume, config) if resume is not None else None
    if saved is not None and saved.manifest.get("status") == "captured":
        return _reconstruct_captured(saved, show_stages)
    timer = StageTimer()
    wall0 = time.perf_counter()
    config = saved.config if saved else (config or ScanConfig())
    hanging = saved.hanging if saved else 0
    with timer("setup"):
        viewer = meshcat_if(meshcat)
        world = setup_world(config, viewer, hanging)
        live = _live_view(world, viewer)
    if saved is None:
        with timer("viewpoints"):
            store, views = _start_new(config, out_dir, force, world)
        hangings = _passes(views, config.hangings)
    else:
        store, views, hangings = saved.store, list(saved.views), saved.hangings
        store.update_manifest(status="running")
    # Per-view work runs beside the capture loop when the scan reconstructs at its end.
    stream = ViewStream(saved or open_scan(store.root)) if config.reconstruct else None
    run = _PassRunner(config, world, store, views, live, viewer, timer, progress, stream)
    with interruptible(run), log_file(store.root / "scan.log"):
        try:
            summary = run.passes(hangings, hanging)
        finally:
            streamed = stream.finish() if stream else None
    status = "interrupted" if summary.state.value == "aborted" else "captured"
    skipped = [{"index": o.index, "reason": o.reason} for o in summary.skipped]
    store.update_manifest(status=status, skipped_views=skipped)

    def report() -> dict:
        out = _scan_report(config, store, summary, run.tour_cost_s, len(views), timer, wall0)
        if run.monitor is not None:
            out["monitor"] = run.monitor.report()
        if streamed is not None:
            seconds = streamed.processing_s()
            out["processing_s"] = sum(seconds.values())
            out["processing_hidden_s"] = processing_hidden_s(summary.outcomes, seconds)
        return out

    _write_scan_report(store, report())
    if config.reconstruct and status == "captured":
        with timer("reconstruction"):
            run_reconstruct(saved or open_scan(store.root), streamed=streamed, progress=show_stages)
        store.update_manifest(status="complete")
        _write_scan_report(store, report())
    return ScanResult(store.root, _read_report(store))


def _passes(views: list[PlannedView], hangings: int) -> tuple[tuple[int, ...], ...]:
    count = len(views) // hangings
    return tuple(
        tuple(v.index for v in views[p * count : (p + 1) * count]) for p in range(hangings)
    )


class _PassRunner:
    """Runs the decision maker over each hanging's views in turn, re-hanging the object in
    between (the simulator turns it; hardware asks the operator), and sums up the runs."""

    def __init__(self, config, world, store, views, live, viewer, timer, progress, stream):
        self.config, self.world, self.store, self.stream = config, world, store, stream
        self.views, self.live, self.viewer = views, live, viewer
        self.timer, self.progress = timer, progress
        self.tour_cost_s = 0.0
        self.machine: DecisionMaker | None = None
        self.abort_requested = False
        self.monitor = ScanMonitor(config.monitor) if config.monitor.enabled else None

    def request_abort(self) -> None:
        self.abort_requested = True
        if self.machine is not None:
            self.machine.request_abort()

    def passes(self, hangings: tuple[tuple[int, ...], ...], first: int) -> RunSummary:
        self.hangings = [list(h) for h in hangings]
        summaries = []
        for hanging in range(first, len(hangings)):
            if hanging > first:
                with self.timer("rehang"):
                    self.world = self.world.rehang(hanging, len(hangings), self.viewer)
                self.store.update_manifest(hanging=hanging)
                log.info("re-hung the object for hanging %d of %d", hanging + 1, len(hangings))
            if self.monitor is not None:
                with self.timer("monitor_start"):
                    self.monitor.start(self.world)
            summaries.append(self._one_pass(set(self.hangings[hanging])))
            if self._aborted(summaries):
                break
            summaries += self._extra_views(hanging)
            if self._aborted(summaries):
                break
        return _combined(summaries)

    def _aborted(self, summaries: list[RunSummary]) -> bool:
        return summaries[-1].state.value == "aborted" or self.abort_requested

    def _extra_views(self, hanging: int) -> list[RunSummary]:
        """Next-best views for this hanging (up to views.max_extra_views), each captured at
        once; recorded in the manifest like the planned views, so a resume keeps them."""
        settings = self.config.views
        manifest = self.store.read_manifest()
        done = manifest.get("extra_views_done", [])
        if settings.max_extra_views == 0 or hanging in done:
            return []
        captured = set(self.store.captured_indices())
        indices = [i for i in self.hangings[hanging] if i in captured]
        with self.timer("next_best_view"):
            fused, centres = model_so_far(
                open_scan(self.store.root), indices, self.world.X_FC, self.world.stereo
            )
            model = CoverageModel(fused, centres)
        centre = np.array(self.config.scan_center_m)
        directions = np.array(manifest.get("reachable_directions", []), float).reshape(-1, 3)
        taken = [v.direction for v in self.views if v.index in set(self.hangings[hanging])]
        q_home = self.world.robot.joint_positions()
        summaries = []
        for _ in range(settings.max_extra_views):
            with self.timer("next_best_view"):
                choice = model.best(centre, settings.radius_m, directions, taken)
            if choice is None or choice.gain < settings.min_gain:
                log.info("next-best view: best gain below %.3f, stopping", settings.min_gain)
                break
            taken.append(choice.direction)
            view = planned_view(
                max(v.index for v in self.views) + 1,
                centre,
                choice.direction,
                settings,
                lambda vp: self.world.planner.reachable(vp, q_home),
                lambda q: self.world.planner.estimate_duration_s(q_home, q),
            )
            if view is None:
                continue
            self.views.append(view)
            self.hangings[hanging].append(view.index)
            self.store.update_manifest(
                viewpoints=views_to_manifest(self.views),
                hangings=self.hangings,
                pose_count=len(self.views),
            )
            log.info("next-best view %d: gain %.3f of the surface", view.index, choice.gain)
            summaries.append(self._one_pass({view.index}))
            if self._aborted(summaries):
                return summaries
            if view.index in set(self.store.captured_indices()):
                model.add(centre + settings.radius_m * choice.direction)
        self.store.update_manifest(extra_views_done=[*done, hanging])
        return summaries

    def _one_pass(self, indices: set[int]) -> RunSummary:
        done = set(self.store.captured_indices())
        todo = [v for v in self.views if v.index in indices and v.index not in done]
        robot = self.world.robot
        with self.timer("ordering"):
            tour = plan_tour(robot.joint_positions(), todo, self.world.planner.estimate_duration_s)
        self.tour_cost_s += tour.cost_s
        if self.monitor is not None and not self.monitor.checked:
            # Every hanging repeats about this tour; each capture waits capture_dwell_s.
            passes = len(self.hangings)
            rests = len(self.views) * self.config.monitor.capture_dwell_s
            self.monitor.check_intruders(self.monitor.clock_s + passes * tour.cost_s + rests)
            self.monitor.checked = True
        machine = _decision_maker(
            self.config,
            self.world,
            self.store,
            self.views,
            todo,
            tour,
            self.live,
            self.stream,
            self.monitor,
        )
        self.machine = machine
        if self.abort_requested:
            machine.request_abort()
        total = len(self.views)
        if self.progress:
            self.progress(len(done), total)
            machine.on_view_done = lambda _: self.progress(
                len(self.store.captured_indices()), total
            )
        with self.timer("capture"):
            return _run_machine(machine, self.store)


def _combined(summaries: list[RunSummary]) -> RunSummary:
    stage_s: dict[str, float] = {}
    for s in summaries:
        for k, v in s.stage_s.items():
            stage_s[k] = stage_s.get(k, 0.0) + v
    return RunSummary(
        summaries[-1].state,
        [o for s in summaries for o in s.outcomes],
        sum(s.robot_motion_s for s in summaries),
        stage_s,
        [t for s in summaries for t in s.transitions],
    )


def _run_machine(machine: DecisionMaker, store: CaptureStore) -> RunSummary:
    """The decision maker's run; a failed write (a full disk) or a cell monitor that stopped
    the arm ends the scan as interrupted, keeping every capture made so far, and says how to
    continue."""
    try:
        return machine.run()
    except (MonitorStoppedError, StorageError) as e:
        # On a full disk the manifest may keep "running", which resumes the same way.
        with suppress(OSError):
            store.update_manifest(status="interrupted")
        first = "free space, then continue" if isinstance(e, StorageError) else "continue"
        raise type(e)(
            f"{e}; the {len(store.captured_indices())} captures so far are kept: {first} "
            f"with: scanner scan --resume {store.root}"
        ) from None


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
    store.update_manifest(status="complete")
    _write_scan_report(store, {"status": "complete"})
    return ScanResult(store.root, _read_report(store))

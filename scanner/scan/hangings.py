"""The capture part of a scan: the decision maker over each hanging's (pass's) views in turn, the
object presented anew in between (scan/presentation: re-hung by the operator, or turned by the
turntable), next-best views after each pass's planned ones, and the runs summed up."""

from __future__ import annotations

import dataclasses
import logging
import time
from contextlib import suppress

import numpy as np

from planners.tour import Tour, plan_tour
from reconstruction.common.errors import StorageError
from reconstruction.common.stage_timer import cpu_seconds
from robots.drivers.staubli_val3 import RobotStoppedError
from robots.simulation.truth import record_hung_pose
from scanner.configs.scan import ScanConfig
from scanner.monitor.cell_monitor import MonitorStoppedError
from scanner.monitor.scan_monitor import ScanMonitor
from scanner.reconstruct.scan_views import model_so_far
from scanner.reconstruct.view_stream import ViewStream, with_stream
from scanner.scan.auto_hangings import HangingAssessor, decide
from scanner.scan.decision import DecisionMaker, FixedViewList, RunSummary
from scanner.scan.early_alignment import EarlyAlignments
from scanner.scan.next_best_view import CoverageModel
from scanner.scan.presentation import presentation_for
from scanner.scan.viewpoints import planned_view
from scanner.scan.world import ScanWorld, WatchedRobot, live_cloud, software_kinematics
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.manifest import open_scan, views_to_manifest
from scanner.scan_dir.quick_alignments import record_quick_alignments
from scanner.scan_dir.views import PlannedView

log = logging.getLogger("scanner.scan.hangings")


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
        robot, camera = monitor.drivers(robot, camera, world.planner)
    return DecisionMaker(
        world.planner,
        robot,
        camera,
        store,
        FixedViewList(ordered, preferred),
        len(views),
        software_kinematics(config),
        config.machine,
        process=with_stream(
            live_cloud(live, config, world.camera_model, world.X_FC) if live else None, stream
        ),
    )


class HangingRunner:
    """Runs the decision maker over each hanging's views in turn, re-hanging the object in
    between (the simulator turns it; hardware asks the operator), and sums up the runs."""

    def __init__(self, config, world, store, views, live, viewer, timer, progress, stream):
        self.config, self.world, self.store, self.stream = config, world, store, stream
        self.views, self.live, self.viewer = views, live, viewer
        self.timer, self.progress = timer, progress
        self.tour_cost_s = 0.0
        self.machine: DecisionMaker | None = None
        self.abort_requested = False
        self.monitor = (
            ScanMonitor(config.monitor, world.planner.arm) if config.monitor.enabled else None
        )
        self.assessor: HangingAssessor | None = None
        self.presentation = presentation_for(config, store)
        # Each further pass's alignment searched for on its first views, while the rest are
        # captured; one thread, beside the scan's own.
        self.early = EarlyAlignments(store, stream is not None, self._assessor, timer)
        # (wall, CPU seconds) when the last capture was stored: the wait for the model starts.
        self.last_capture: tuple[float, float] | None = None

    def request_abort(self) -> None:
        self.abort_requested = True
        if self.machine is not None:
            self.machine.request_abort()

    def passes(self, hangings: tuple[tuple[int, ...], ...], first: int) -> RunSummary:
        """Every hanging from `first` on (a resumed scan: the one it stopped in; a pending
        re-hang is asked for again; a later hanging whose views are all captured is not, as
        after a hanging scanned again); with `hangings: auto`, more hangings while the model is
        not complete."""
        self.hangings = [list(h) for h in hangings]
        try:
            return self._passes(first)
        finally:
            self.early.stop()

    def _passes(self, first: int) -> RunSummary:
        summaries = []
        hanging = first
        self.world = self.presentation.begin(self.world, first)
        while hanging < len(self.hangings):
            if hanging > first and set(self.hangings[hanging]) <= set(
                self.store.captured_indices()
            ):
                hanging += 1
                continue
            manifest = self.store.read_manifest()
            if hanging > first or manifest.get("pending_rehang") == hanging:
                self._rehang(hanging, manifest)
            if self.monitor is not None:
                with self.timer("monitor_start"):
                    self.monitor.start(self.world)
            if self.stream is not None:
                self.stream.hanging = hanging  # its views are paired among themselves
            summaries.append(self._one_pass(set(self.hangings[hanging])))
            if self._aborted(summaries):
                break
            summaries += self._extra_views(hanging)
            if self._aborted(summaries):
                break
            self.early.done(hanging)
            if self.config.auto_hangings and hanging == len(self.hangings) - 1:
                self._after_hanging(hanging)
            self.early.prepare(self.hangings, hanging + 1, set(self.store.captured_indices()))
            hanging += 1
        return _combined(summaries)

    def _rehang(self, hanging: int, manifest: dict) -> None:
        request = manifest.get("hanging_requests", {}).get(str(hanging))
        if manifest.get("rescanning") == hanging:
            # Scanned again after it did not align: the instruction was relative to how the
            # object hung before that hanging, which it no longer does.
            request = None
        with self.timer("rehang"):
            self.world = self.presentation.present(self.world, hanging, request, self.viewer)
        if self.world.sim is not None:
            record_hung_pose(self.store.root / "truth.yaml", hanging, self.world.sim.truth.X_WO)
        again = {"rescanning": None} if "rescanning" in manifest else {}
        self.store.update_manifest(hanging=hanging, pending_rehang=None, **again)
        log.info("presented the object (%s) for pass %d", self.presentation.kind, hanging + 1)

    def _assessor(self) -> HangingAssessor:
        """The scan's quick models, made on first use (after a resume too)."""
        if self.assessor is None:
            self.assessor = HangingAssessor(open_scan(self.store.root), self.stream)
        return self.assessor

    def _after_hanging(self, hanging: int) -> None:
        """Estimate what the hangings so far have seen; below the target, plan the next
        hanging and record the instruction (the loop then asks for it)."""
        manifest = self.store.read_manifest()
        journal = list(manifest.get("hanging_log", []))
        if any(entry["hanging"] == hanging + 1 for entry in journal):
            return  # decided before an interruption: the pending re-hang stands
        with self.timer("coverage_check"):
            captured = set(self.store.captured_indices())
            assessment = self._assessor().assess(self.hangings, hanging, captured)
        # The reconstruction refines these rather than searching for them again.
        record_quick_alignments(self.store, list(self.assessor.alignments.values()))
        coverage = [entry["coverage_after"] for entry in journal] + [assessment.fraction]
        limit = self.presentation.max_passes
        config = self.config
        if limit is not None and limit < config.max_hangings:
            config = dataclasses.replace(config, max_hangings=limit)
        decision = decide(config, coverage, assessment.failures)
        entry = {
            "hanging": hanging + 1,
            "coverage_before": coverage[-2] if len(coverage) > 1 else 0.0,
            "coverage_after": assessment.fraction,
            "quick_alignment_verified": assessment.verified,
        }
        log.info("after hanging %d: coverage %.3f; %s", hanging + 1, coverage[-1], decision.reason)
        if not decision.another:
            self.store.update_manifest(hanging_log=[*journal, entry], stop_reason=decision.reason)
            return
        with self.timer("next_hanging"):
            request = self._request(hanging + 1, assessment.seen)
        if request is None:
            reason = f"nothing left unseen that another hanging would show ({decision.reason})"
            self.store.update_manifest(hanging_log=[*journal, entry], stop_reason=reason)
            return
        entry["next"] = {"asked_because": decision.reason, **request}
        self._add_hanging(hanging + 1, request, [*journal, entry])

    def _request(self, hanging: int, seen) -> dict | None:
        """The request for pass `hanging`: the next-best re-hang or turn (the presentation's)."""
        planned = set(self.hangings[0][: self._per_hanging()])
        directions = np.array([v.direction for v in self.views if v.index in planned])
        return self.presentation.plan(hanging, seen, directions)

    def _per_hanging(self) -> int:
        return int(self.store.read_manifest().get("views_per_hanging", len(self.hangings[0])))

    def _add_hanging(self, hanging: int, request: dict, journal: list) -> None:
        """The next pass's views (the first hanging's planned ones, numbered on) and the
        instruction, recorded before anything moves (a resume asks for it again)."""
        base = max(v.index for v in self.views) + 1
        planned = set(self.hangings[0][: self._per_hanging()])
        new = [
            dataclasses.replace(v, index=base + k)
            for k, v in enumerate(v for v in self.views if v.index in planned)
        ]
        self.views += new
        self.hangings.append([v.index for v in new])
        requests = {**self.store.read_manifest().get("hanging_requests", {}), str(hanging): request}
        self.store.update_manifest(
            viewpoints=views_to_manifest(self.views),
            hangings=self.hangings,
            pose_count=len(self.views),
            hanging_requests=requests,
            hanging_log=journal,
            pending_rehang=hanging,
        )
        log.info("asking for hanging %d: %s", hanging + 1, request["words"])

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
                open_scan(self.store.root), indices, self.world.X_FC, self.world.camera_model
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
        hanging = self.stream.hanging if self.stream is not None else 0

        def view_done(outcome) -> None:
            if outcome.captured:
                self.last_capture = (time.perf_counter(), cpu_seconds())
            captured = self.store.captured_indices()
            if self.progress:
                self.progress(len(captured), total)
            self.early.on_capture(self.hangings, hanging, set(captured))

        if self.progress:
            self.progress(len(done), total)
        machine.on_view_done = view_done
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
    except (MonitorStoppedError, RobotStoppedError, StorageError) as e:
        # On a full disk the manifest may keep "running", which resumes the same way.
        with suppress(OSError):
            store.update_manifest(status="interrupted")
        first = "free space, then continue" if isinstance(e, StorageError) else "continue"
        raise type(e)(
            f"{e}; the {len(store.captured_indices())} captures so far are kept: {first} "
            f"with: scanner scan --resume {store.root}"
        ) from None

"""Per-view work while the robot moves: stereo, cropping, robot/cell point removal and the
outlier filter of each capture (and its sampling for the hand-eye fit) run on worker threads
beside the capture loop, and pairwise ICP of each view against the earlier views it overlaps on
one more thread, in capture order (`reconstruction.registration.incremental`), so that the
reconstruction at the end of a scan only optimises the pose graph, corrects the hand-eye
transform and builds surfaces.

The workers take each capture as it was stored (or read it back from the scan directory) and
run exactly the functions the offline `scanner reconstruct` runs, with the scan's own camera
model, X_FC and processing settings: the streamed views are what the offline run would
compute, and the reconstruction uses them only when those three are still the ones it
reconstructs with. At most `max_pending` captures are being processed or registered (the
capture loop waits beyond that, one per worker by default), so memory stays bounded and the
work left when the last picture is taken is that of two views at most. Unbounded, the single
registration thread fell ten views behind on the simulator, whose captures come faster than a
robot's (6 s of the wait after the last picture).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.handeye.refine import prepare_view
from reconstruction.pipeline import solver_processes
from reconstruction.registration.filtering import VIEW_THREADS, FilteredCloud, filter_view
from reconstruction.registration.incremental import ArrivingPairs
from reconstruction.registration.views import ViewCloud
from reconstruction.surfaces.poisson_solver import start_solver
from robots.sensors import sensor_named
from scanner.configs.typed_yaml import to_dict
from scanner.reconstruct.scan_views import (
    capture_view,
    geometry_filter,
    prepare_sensor,
    with_roi_centre,
)
from scanner.scan_dir.captures import Capture
from scanner.scan_dir.manifest import SavedScan

log = logging.getLogger("scanner.scan.run")


def settings_key(scan: SavedScan, processing, X_FC: np.ndarray, stereo) -> tuple:
    """What per-view results depend on besides the captures: equal keys, equal results."""
    return (
        str(scan.root.resolve()),
        repr(to_dict(processing)),
        np.asarray(X_FC, float).tobytes(),
        repr(sensor_named(scan.sensor).model_to_dict(stereo)),
    )


@dataclass(frozen=True, eq=False)
class StreamedView:
    """One capture's per-view results: its view (cloud in C, depth map), its joint positions,
    its filtered cloud (None when too few points were left: the reconstruction skips it), and
    the seconds the worker spent on it."""

    view: ViewCloud
    q_rad: np.ndarray
    cloud: FilteredCloud | None
    seconds: float


@dataclass(frozen=True, eq=False)
class StreamedViews:
    """What the workers finished: per capture index, the captures they could not read, and
    the pairs registered as the views arrived (None when the scan registers no pairs)."""

    key: tuple
    views: dict[int, StreamedView] = field(default_factory=dict)
    failed: dict[int, str] = field(default_factory=dict)
    arriving: ArrivingPairs | None = None
    registration_s: dict[int, float] = field(default_factory=dict)

    def processing_s(self) -> dict[int, float]:
        return {i: v.seconds for i, v in self.views.items()}


class ViewStream:
    """`submit(index)` after each stored capture; `finish()` waits and returns the results."""

    def __init__(
        self, scan: SavedScan, max_pending: int = VIEW_THREADS, workers: int = VIEW_THREADS
    ) -> None:
        self.scan = scan
        processing = scan.config.processing
        self._params = processing.stereo
        self._config = with_roi_centre(
            processing.reconstruction, np.array(scan.config.scan_center_m)
        )
        self._sensor = prepare_sensor(scan, scan.camera_model)
        self._joints: dict[int, np.ndarray] = {}
        self._remove = geometry_filter(
            scan.config,
            scan.X_FC_nominal,
            scan.camera_model,
            self._joints,
            processing.remove_margin_m,
        )
        config = self._config
        pairs = config.icp.enabled or config.handeye.enabled
        self._result = StreamedViews(
            settings_key(scan, processing, scan.X_FC_nominal, scan.camera_model),
            arriving=ArrivingPairs(config.icp, scan.X_FC_nominal) if pairs else None,
        )
        # The Poisson solver processes the reconstruction will use, started now: their imports
        # (about 1 s of CPU each) then run while the robot moves, not after the last picture.
        start_solver(solver_processes(config, coverage=True))
        self._slots = threading.BoundedSemaphore(max_pending)
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="view-stream")
        # One thread registers the views in the order they were submitted (capture order).
        self._registrar = ThreadPoolExecutor(1, thread_name_prefix="view-pairs")
        self._futures: list[Future] = []
        # The hanging the next submitted captures belong to (the scan's runner sets it).
        self.hanging = 0

    def submit_stored(self) -> None:
        """A resumed scan: its captures so far, in capture order, before any new one, so
        that the pairs are those an uninterrupted run registered (the workers read them back
        from the files)."""
        scan, store = self.scan, self.scan.store
        hanging_of = {i: h for h, indices in enumerate(scan.hangings) for i in indices}
        done = store.captured_indices()
        stamps = {i: store.capture_stamp_s(i) for i in done}
        for index in sorted(done, key=lambda i: (math.isnan(stamps[i]), stamps[i], i)):
            self.submit(index, None, hanging_of.get(index, 0))

    def submit(
        self, index: int, capture: Capture | None = None, hanging: int | None = None
    ) -> None:
        """Process capture `index`: the stored capture itself when given (no decoding of its
        images again; at most `max_pending` such are waiting), else read back from the scan
        directory; then register it against the earlier views of its hanging (`hanging`, else
        the current one)."""
        # A capture in memory holds a slot until its view is registered (processed, when
        # nothing is registered): the capture loop waits while the per-view work lags.
        held = capture is not None
        if held:
            self._slots.acquire()
        registering = self._result.arriving is not None
        processed = self._pool.submit(self._process, index, capture, held and not registering)
        self._futures.append(processed)
        if registering:
            h = self.hanging if hanging is None else hanging
            self._futures.append(self._registrar.submit(self._register, index, h, processed, held))

    def _register(self, index: int, hanging: int, processed: Future, release: bool) -> None:
        try:
            processed.result()
            streamed = self._result.views.get(index)
            if streamed is None or streamed.cloud is None:
                return  # unreadable or nearly empty: the final stage decides about it
            t0 = time.perf_counter()
            self._result.arriving.add(index, hanging, streamed.cloud, streamed.view.X_WF)
            self._result.registration_s[index] = time.perf_counter() - t0
        finally:
            if release:
                self._slots.release()

    def _process(self, index: int, capture: Capture | None = None, release: bool = False) -> None:
        t0 = time.perf_counter()
        try:
            view, q = capture_view(
                self.scan, index, self._sensor, self.scan.X_FC_nominal, self._params, capture
            )
            self._joints[index] = q
            cloud = filter_view(
                index,
                view.points_C,
                view.colors,
                view.X_WF @ self.scan.X_FC_nominal,
                self._config.filter,
                self._remove,
            )
            kept = cloud if len(cloud) >= self._config.filter.min_points else None
            handeye = self._config.handeye
            if kept is not None and handeye.enabled and handeye.refine:
                # Sampled now for the hand-eye fit after the last picture (made once a cloud).
                prepare_view(kept, handeye.fine_fit)
            seconds = time.perf_counter() - t0
            self._result.views[index] = StreamedView(view, q, kept, seconds)
        except ScannerError as e:
            # The final stage reads the capture again and reports it as offline runs do.
            self._result.failed[index] = str(e)
        finally:
            if release:
                self._slots.release()

    def so_far(self) -> StreamedViews:
        """What the workers made of every capture submitted so far (waits for them)."""
        for f in list(self._futures):
            f.result()
        return self._result

    def finish(self) -> StreamedViews:
        """Wait for every submitted capture; a programming error in the worker is raised here."""
        self._pool.shutdown(wait=True)
        self._registrar.shutdown(wait=True)
        for f in self._futures:
            f.result()
        return self._result


def processing_hidden_s(outcomes, seconds: dict[int, float]) -> float:
    """Per-view work that fits in the robot's motion to the next view (the simulated motion
    clock): for each streamed capture, min(its processing time, the next motion)."""
    hidden = 0.0
    for outcome, following in zip(outcomes, outcomes[1:]):
        if outcome.index in seconds:
            hidden += min(seconds[outcome.index], following.motion_s)
    return hidden


def with_stream(process, stream: ViewStream | None):
    """The decision maker's PROCESS step: the given one (the live view), then the capture
    handed to the stream."""
    if stream is None:
        return process

    def both(capture) -> None:
        if process is not None:
            process(capture)
        stream.submit(capture.pose_index, capture)

    return both

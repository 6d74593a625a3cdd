"""The views of saved scans, ready for the reconstruction: stereo clouds of the captures (one
scan or several, with indices made unique), the point filter of each scan's cell, the truth
files when the simulator wrote them, and a quick model of some captures to plan views on."""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.config import ReconstructionConfig
from reconstruction.depth.camera_model import CameraModel
from reconstruction.evaluation.metrics import TriangleSurface
from reconstruction.evaluation.support import SupportPlane
from reconstruction.registration.filtering import VIEW_THREADS, filter_views
from reconstruction.registration.views import ViewCloud
from reconstruction.stereo.params import StereoParams
from reconstruction.surfaces.fixture import FixtureLine
from reconstruction.surfaces.fused import FusedCloud, fuse_clouds
from robots.models.workcell import keep_out_radius_m
from robots.sensors import Sensor, sensor_named
from scanner.configs.scan import ProcessingConfig, ScanConfig
from scanner.scan_dir.captures import Capture
from scanner.scan_dir.manifest import SavedScan

log = logging.getLogger("scanner.reconstruct.stages")


@dataclass(frozen=True, eq=False)
class CaptureViews:
    """The stereo stage's output: a view per readable capture, the captures skipped (index and
    reason), and the measured joint positions of each view (for the robot/cell point filter)."""

    views: list[ViewCloud]
    skipped: list[dict]
    joints: dict[int, np.ndarray]


def capture_views(
    scan: SavedScan,
    sensor: PreparedSensor | object,
    X_FC: np.ndarray,
    params: StereoParams,
    indices: Sequence[int] | None = None,
    ready: Mapping[int, tuple[ViewCloud, np.ndarray]] | None = None,
    on_view: Callable[[], None] | None = None,
) -> CaptureViews:
    """The clouds of every readable capture (or of those among `indices`) by the scan's
    sensor (`sensor`: prepare_sensor's, or what the kind's prepare() made); damaged captures
    are reported and skipped. `ready`: (view, joints) of captures already done by
    the same settings (streamed during the scan). `on_view()` after each capture (progress)."""
    out = CaptureViews([], [], {})
    wanted = None if indices is None else set(indices)
    ready = ready or {}
    todo = [i for i in scan.store.captured_indices() if wanted is None or i in wanted]

    def one(index: int) -> tuple[ViewCloud, np.ndarray] | ScannerError:
        if index in ready:
            return ready[index]
        try:
            return capture_view(scan, index, sensor, X_FC, params)
        except ScannerError as e:
            return e

    with ThreadPoolExecutor(max_workers=VIEW_THREADS) as pool:
        for index, done in zip(todo, pool.map(one, todo)):
            if isinstance(done, ScannerError):
                log.warning("capture %d skipped: %s", index, done)
                out.skipped.append({"index": index, "reason": str(done)})
                continue
            out.views.append(done[0])
            out.joints[index] = done[1]
            if on_view is not None:
                on_view()
    return out


@dataclass(frozen=True, eq=False)
class PreparedSensor:
    """A scan's sensor kind and what it computed once of the camera model (a stereo pair's
    rectification, an RGB-D device's model itself) to turn captures into clouds."""

    sensor: Sensor
    prepared: object


def prepare_sensor(scan: SavedScan, model: CameraModel) -> PreparedSensor:
    """The scan's sensor (its manifest's kind), prepared for the camera model `model`."""
    sensor = sensor_named(scan.sensor)
    return PreparedSensor(sensor, sensor.prepare(model))


def capture_view(
    scan: SavedScan,
    index: int,
    ready: PreparedSensor | object,
    X_FC: np.ndarray,
    params: StereoParams,
    capture: Capture | None = None,
) -> tuple[ViewCloud, np.ndarray]:
    """One capture's cloud (stereo, or the depth camera's) and depth map, and its measured
    joint positions; a damaged or mismatched capture raises ScannerError (its reason).
    `capture`: the capture as it was just stored (its PNGs are lossless: reading them back
    gives the same arrays), else read."""
    if capture is None:
        capture = scan.store.read_capture(index)
    if not isinstance(ready, PreparedSensor):
        # What prepare() made, given alone (a Rectification, an RgbdCamera): the scan's kind.
        ready = PreparedSensor(sensor_named(scan.sensor), ready)
    sensor = ready.sensor
    if capture.sensor != sensor.capture_format:
        raise ScannerError(
            f"a {capture.sensor} capture in a scan whose camera is {sensor.model_words}"
        )
    centre = np.array(scan.config.scan_center_m, float)
    radius = keep_out_radius_m(scan.config.cell)
    X_WF = scan.X_WF(capture)
    X_WC = X_WF @ X_FC
    cloud = sensor.cloud(ready.prepared, capture, X_WC, centre, radius, params)
    view = ViewCloud(index, cloud.points_C, cloud.colors, X_WF, cloud.depth, capture.stamp_s)
    return view, capture.q_rad


def load_truth_of(scan_dir: Path):
    """(the simulator's Truth record, the true surface in W, the whole truth file), or None
    without truth.yaml."""
    path = scan_dir / "truth.yaml"
    if not path.is_file():
        return None
    from reconstruction.common.mesh_files import read_triangle_mesh
    from robots.simulation.truth import load_truth

    truth, raw = load_truth(path)
    mesh = read_triangle_mesh(scan_dir / raw.get("mesh", "truth_mesh.ply"))
    if len(mesh.triangles) == 0:
        raise ScannerError(f"{scan_dir}: truth mesh missing or empty")
    surface = TriangleSurface(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    return truth, surface, raw


def geometry_filter(
    config: ScanConfig,
    X_FC: np.ndarray,
    stereo: CameraModel,
    joints: dict,
    margin_m: float,
    support_margin_m: float | None = None,
):
    """remove_points(points_W, index) of the scan's cell: points within `margin_m` of the
    robot, its tool and the cell's geometry at the view's joints, and on a table or turntable
    every point less than `support_margin_m` (default: the scan's `processing`) above its top.
    A pass's points are in its own frame here (the pipeline takes them back there), where the
    support stands."""
    from robots.arms.default import arm_of
    from robots.models.point_filter import make_geometry_filter
    from robots.models.workcell import build_workcell

    cell = build_workcell(
        config.cell,
        None,
        X_FC,
        stereo.X_CR,
        arm_of(config.robot),
        presentation=config.presentation,
    )
    keep = make_geometry_filter(cell, margin_m)
    support = support_plane(config)
    if support is None:
        return lambda points_W, index: keep(points_W, joints[index])
    above_m = config.processing.support_margin_m if support_margin_m is None else support_margin_m
    return lambda points_W, index: (  # noqa: E731
        keep(points_W, joints[index]) & support.exposed(points_W, above_m)
    )


def fixture_line(config: ScanConfig) -> FixtureLine:
    """The rod the object hangs from: the vertical above the scan centre (in every hanging:
    the cell holds the rod, the operator hangs the object anew from it); on a turntable, the
    post below it; on the table, its leg (the half diagonal of its square section)."""
    cell = config.cell
    if config.presentation == "turntable":
        from robots.models.turntable import POST_RADIUS_M

        return FixtureLine(tuple(cell.object_center_m), (0.0, 0.0, -1.0), POST_RADIUS_M)
    if config.presentation == "table":
        from robots.models.table import LEG_SIDE_M

        return FixtureLine(tuple(cell.object_center_m), (0.0, 0.0, -1.0), LEG_SIDE_M / 2**0.5)
    return FixtureLine(tuple(cell.object_center_m), (0.0, 0.0, 1.0), cell.rod_radius_m)


def support_plane(config: ScanConfig) -> SupportPlane | None:
    """The top of what holds the object from below in each pass (the table's top, the
    turntable's disc; fixed in the cell, so in each pass's own frame the same), None for a
    hanging: the views see nothing on or below it."""
    if config.presentation == "hanging":
        return None
    from robots.models.turntable import turntable_geometry

    # The table's top and the disc's stand at the same place (robots/models).
    return SupportPlane(np.array(turntable_geometry(config.cell).p_top_W), np.array([0, 0, 1.0]))


def with_roi_centre(config: ReconstructionConfig, centre: np.ndarray) -> ReconstructionConfig:
    """The region of interest around the scan centre unless the configuration placed it."""
    if config.filter.roi.center_m is not None:
        return config
    roi = replace(config.filter.roi, center_m=tuple(float(c) for c in centre))
    return replace(config, filter=replace(config.filter, roi=roi))


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
    fixtures: list[FixtureLine] = field(default_factory=list)  # per hanging, its rod's line
    # Per hanging, the top of its support in its own frame (None: it hung).
    supports: list[SupportPlane | None] = field(default_factory=list)
    robots: list[str] = field(default_factory=list)  # per scan, its configuration's arm


def gather_views(
    scans: list[SavedScan],
    processing: ProcessingConfig,
    X_FC: np.ndarray | None = None,
    stereo: CameraModel | None = None,
    ready: Mapping[int, tuple[ViewCloud, np.ndarray]] | None = None,
    on_view: Callable[[], None] | None = None,
) -> Gathered:
    """Stereo clouds of every capture of every scan (each with its own camera model and X_FC
    unless given), with the point filter of each scan's cell. `ready`: views of the first
    scan already computed with these settings."""
    out = Gathered([], [], {}, [], {}, [], None)
    filters = []
    for k, scan in enumerate(scans):
        camera = stereo or scan.camera_model
        X = scan.X_FC_nominal if X_FC is None else X_FC
        captured = capture_views(
            scan,
            prepare_sensor(scan, camera),
            X,
            processing.stereo,
            ready=ready if k == 0 else None,
            on_view=on_view,
        )
        offset = k * INDEX_STRIDE
        out.views.extend(replace(v, index=v.index + offset) for v in captured.views)
        out.skipped.extend({**d, "index": d["index"] + offset} for d in captured.skipped)
        out.joints.update({i + offset: q for i, q in captured.joints.items()})
        out.hangings.extend([i + offset for i in h] for h in scan.hangings)
        out.fixtures.extend(fixture_line(scan.config) for _ in scan.hangings)
        out.supports.extend(support_plane(scan.config) for _ in scan.hangings)
        out.scan_of.update({v.index + offset: k for v in captured.views})
        out.truths.append(load_truth_of(scan.root))
        out.robots.append(scan.config.robot)
        filters.append(
            geometry_filter(
                scan.config,
                X,
                camera,
                captured.joints,
                processing.remove_margin_m,
                processing.support_margin_m,
            )
        )
    remove = lambda points_W, index: filters[index // INDEX_STRIDE](  # noqa: E731
        points_W, index % INDEX_STRIDE
    )
    return replace(out, remove=remove)


def model_so_far(
    scan: SavedScan, indices: Sequence[int], X_FC: np.ndarray, stereo: CameraModel
) -> tuple[FusedCloud, list[np.ndarray]]:
    """The fused cloud of some captures at their kinematic poses (no registration: a quick
    model to plan more views on), and their camera centres."""
    processing = scan.config.processing
    config = with_roi_centre(processing.reconstruction, np.array(scan.config.scan_center_m))
    captured = capture_views(scan, prepare_sensor(scan, stereo), X_FC, processing.stereo, indices)
    remove = geometry_filter(
        scan.config,
        X_FC,
        stereo,
        captured.joints,
        processing.remove_margin_m,
        processing.support_margin_m,
    )
    views, clouds, _ = filter_views(captured.views, X_FC, config.filter, remove)
    X_WC = [v.X_WF @ X_FC for v in views]
    fused = fuse_clouds(clouds, X_WC, config.surfaces.fused_voxel_size_m)
    return fused, [X[:3, 3] for X in X_WC]

"""`scanner scan`: set up the (simulated) cell, choose and order views, run the decision maker,
store every capture, then reconstruct and report."""

from __future__ import annotations

import json
import logging
import signal
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from planners.ik import Viewpoint
from planners.planner import Planner
from reconstruction.calibration_file import load_calibration
from reconstruction.camera_model import StereoCamera, stereo_camera_to_dict
from reconstruction.errors import ScannerError
from robots import camera_tool
from robots.drivers import RobotDriver, StereoCameraDriver, load_hardware
from robots.kinematics import Kinematics
from robots.rx60 import RX60, rx60_urdf
from robots.simulation import Simulation, cache_dir, create_simulation, object_vertices_W
from robots.truth import save_truth
from robots.workcell import Workcell, build_workcell, keep_out_radius_m
from scanner.captures import CaptureStore, atomic_write_text
from scanner.config import ScanConfig, scan_config_from_dict, scan_config_to_dict
from scanner.decision import DecisionMaker, FixedViewList, MachineSettings, RunSummary
from scanner.reconstruct import run_reconstruct
from scanner.report import write_summary
from scanner.tour import plan_tour
from scanner.viewpoints import PlannedView, ViewOption, generate_viewpoints

log = logging.getLogger("scanner.scan")


@dataclass
class ScanResult:
    scan_dir: Path
    report: dict
    summary: RunSummary


@dataclass
class _Stages:
    seconds: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def __call__(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0


def _views_to_manifest(views: list[PlannedView]) -> list[dict]:
    return [
        {
            "index": v.index,
            "direction": [float(x) for x in v.direction],
            "p_WM": list(v.viewpoint.p_WM),
            "p_WT": list(v.viewpoint.p_WT),
            "roll_rad": v.viewpoint.roll_rad,
            "options": [
                {"roll_rad": o.roll_rad, "q_rad": [float(x) for x in o.q]} for o in v.options
            ],
        }
        for v in views
    ]


def _views_from_manifest(items: list[dict], where: str) -> list[PlannedView]:
    try:
        return [
            PlannedView(
                int(d["index"]),
                np.array(d["direction"], float),
                Viewpoint(tuple(d["p_WM"]), tuple(d["p_WT"]), float(d["roll_rad"])),
                tuple(
                    ViewOption(float(o["roll_rad"]), np.array(o["q_rad"], float))
                    for o in d["options"]
                ),
            )
            for d in items
        ]
    except (KeyError, TypeError, ValueError) as e:
        raise ScannerError(f"{where}: malformed viewpoint list ({e})") from None


def _interruptible(machine: DecisionMaker):
    """Ctrl-C / SIGTERM ask the machine to stop after the current capture."""

    @contextmanager
    def guard():
        def handler(signum, frame):
            log.warning("signal %d: finishing the current capture, then stopping", signum)
            machine.request_abort()

        previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for s, h in previous.items():
                signal.signal(s, h)

    return guard()


def _check_resume_matches(saved: ScanConfig, requested: ScanConfig | None, where: Path) -> None:
    if requested is None:
        return
    a, b = scan_config_to_dict(saved), scan_config_to_dict(requested)
    differing = sorted(k for k in a if a[k] != b.get(k))
    if differing:
        raise ScannerError(
            f"{where}: the scan was started with a different configuration "
            f"({', '.join(differing)}); resume without changing them or start a new scan"
        )


class _WatchedRobot(RobotDriver):
    """Plays every executed trajectory in Meshcat before the arm takes it."""

    def __init__(self, robot: RobotDriver, live, joint_offsets_rad: np.ndarray) -> None:
        self._robot, self._live, self._offsets = robot, live, joint_offsets_rad

    def joint_positions(self) -> np.ndarray:
        return self._robot.joint_positions()

    def execute(self, trajectory) -> None:
        self._live.play(trajectory, self._offsets)
        self._robot.execute(trajectory)


def software_camera(config: ScanConfig):
    """The stereo model and X_FC the software believes: the calibration file's, else nominal."""
    stereo = config.camera.stereo_camera()
    X_FC = camera_tool.nominal_X_FC(stereo.baseline_m)
    if config.calibration_file:
        calibration = load_calibration(Path(config.calibration_file))
        if calibration.stereo is None:
            raise ScannerError(f"{config.calibration_file}: holds no stereo camera model")
        if calibration.stereo.image_size != stereo.image_size:
            raise ScannerError(
                f"{config.calibration_file}: calibrated for {calibration.stereo.image_size} "
                f"images, the camera delivers {stereo.image_size}"
            )
        return calibration.stereo, calibration.X_FC
    return stereo, X_FC


def _live_cloud(live, config: ScanConfig, stereo, X_FC: np.ndarray):
    """PROCESS state with --meshcat: each capture's stereo cloud (every 4th pixel) joins the
    growing cloud in Meshcat, placed by the kinematic pose and the nominal X_FC."""
    from reconstruction.rectification import compute_rectification
    from reconstruction.stereo import stereo_cloud
    from reconstruction.stereo_params import object_depth_window

    rect = compute_rectification(stereo)
    params = replace(config.processing.stereo, subsample_step_px=4)
    centre = np.array(config.scan_center_m)
    radius = config.cell.object_size_m * np.sqrt(3) / 2

    def process(capture) -> None:
        X_WC = capture.X_WF @ X_FC
        distance = float(np.linalg.norm(centre - X_WC[:3, 3]))
        z_min, z_max = object_depth_window(distance, radius)
        cloud = stereo_cloud(rect, capture.left, capture.right, z_min, z_max, params)
        p_W = cloud.points_C @ X_WC[:3, :3].T + X_WC[:3, 3]
        live.add_cloud(f"{capture.pose_index:04d}", p_W, cloud.colors)

    return process


def check_stereo_reach(config: ScanConfig, stereo) -> None:
    """Refuse, before moving, a standoff at which the stereo camera cannot measure the object.

    Left-image columns below min_disparity + num_disparities have no match in the right image;
    the remaining band must hold at least half the object's image (its bounding sphere's image
    radius f r / d), else most of the object is never measured.
    """
    from reconstruction.rectification import compute_rectification
    from reconstruction.stereo_params import disparity_window, object_depth_window

    radius = keep_out_radius_m(config.cell)
    if config.views.radius_m <= radius:
        raise ScannerError(
            f"views.radius_m: {config.views.radius_m} m puts the camera inside the object's "
            f"bounding sphere ({radius:.3f} m for a {config.cell.object_size_m} m object)"
        )
    rect = compute_rectification(stereo)
    z_min, z_max = object_depth_window(config.views.radius_m, radius)
    min_d, num_d = disparity_window(z_min, z_max, rect.focal_px, rect.baseline_m)
    width = rect.image_size[0]
    usable_px = width - (min_d + num_d)
    needed_px = rect.focal_px * radius / config.views.radius_m
    if usable_px < needed_px:
        raise ScannerError(
            f"views.radius_m: at {config.views.radius_m} m the object spans depths "
            f"{z_min:.3f}-{z_max:.3f} m (disparities {min_d}-{min_d + num_d} px): only "
            f"{max(usable_px, 0)} px of the {width} px wide image can be matched, less than half "
            f"the object's image ({needed_px:.0f} px); use a larger radius"
        )


@dataclass(frozen=True, eq=False)
class _World:
    """What a scan runs on: the simulator's arm and camera or a hardware driver's."""

    robot: RobotDriver
    camera: StereoCameraDriver
    planner: Planner
    stereo: StereoCamera  # what the software believes (nominal or calibrated)
    X_FC: np.ndarray
    sim: Simulation | None  # None on hardware: no truth
    shown_cell: Workcell | None  # the cell Meshcat shows (built with meshcat=)

    @property
    def joint_offsets_rad(self) -> np.ndarray:
        return self.sim.truth.joint_offsets_rad if self.sim else np.zeros(6)


def simulated_cell(config: ScanConfig, meshcat=None) -> Simulation:
    """The true simulated world of a scan: its object, error model and camera design."""
    design = config.camera.stereo_camera()
    return create_simulation(
        config.cell,
        config.object,
        config.error_model,
        design,
        camera_tool.nominal_X_FC(design.baseline_m),
        meshcat=meshcat,
    )


def _setup_world(config: ScanConfig, meshcat=None) -> _World:
    stereo, X_FC = software_camera(config)
    check_stereo_reach(config, stereo)
    sim = hardware = None
    if config.driver:
        hardware = load_hardware(config.driver, config)
    else:
        sim = simulated_cell(config, meshcat)
    planner_cell = build_workcell(
        config.cell, None, X_FC, stereo.X_CR, meshcat=meshcat if hardware else None
    )
    # Scans always cache the roadmap (a second scan of the same cell starts at once).
    roadmaps = config.planner.cache_dir or str(cache_dir() / "roadmaps")
    planner = Planner(planner_cell, X_FC, stereo.X_CR, replace(config.planner, cache_dir=roadmaps))
    if hardware:
        return _World(hardware.robot, hardware.camera, planner, stereo, X_FC, None, planner_cell)
    return _World(sim.robot, sim.camera, planner, stereo, X_FC, sim, sim.workcell)


def _manifest(config: ScanConfig, stereo, X_FC, views, plan_info: dict) -> dict:
    return {
        "object": config.object,
        "config": scan_config_to_dict(config),
        "camera": stereo_camera_to_dict(stereo),
        "X_FC_nominal": X_FC.tolist(),
        "robot": {"model": "staubli_rx60", "urdf_sha256": _sha(rx60_urdf(RX60()))},
        "pose_count": len(views),
        "viewpoints": _views_to_manifest(views),
        **plan_info,
    }


def _sha(text: str) -> str:
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()


@contextmanager
def _log_file(path: Path):
    """Every state transition goes to SCAN_DIR/scan.log (appended on resume); only warnings
    (skipped views, failed captures) reach the terminal, whatever else configured logging."""
    handler = logging.FileHandler(path)
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
    console = logging.StreamHandler()
    console.setLevel(logging.WARNING)
    console.setFormatter(logging.Formatter("scanner: %(levelname)s: %(message)s"))
    root = logging.getLogger("scanner")
    saved = root.level, root.propagate
    root.addHandler(handler)
    root.addHandler(console)
    root.setLevel(logging.INFO)
    root.propagate = False
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.removeHandler(console)
        root.setLevel(saved[0])
        root.propagate = saved[1]
        handler.close()


def _write_truth(store: CaptureStore, sim: Simulation) -> None:
    import open3d as o3d

    vertices_W = object_vertices_W(sim.object_mesh, sim.truth.X_WO)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices_W),
        o3d.utility.Vector3iVector(np.array(sim.object_mesh.triangles)),
    )
    o3d.io.write_triangle_mesh(str(store.root / ".truth_mesh.tmp.ply"), mesh)
    (store.root / ".truth_mesh.tmp.ply").rename(store.root / "truth_mesh.ply")
    save_truth(sim.truth, store.root / "truth.yaml", {"mesh": "truth_mesh.ply"})


def run_scan(
    config: ScanConfig | None,
    out_dir: Path | None,
    resume: Path | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    meshcat: bool = False,
) -> ScanResult:
    """A new scan into `out_dir`, or continue the scan in `resume` (then `config` must be None
    or equal to the saved one)."""
    stages = _Stages()
    wall0 = time.perf_counter()
    if resume is not None:
        store = CaptureStore.open(resume)
        manifest = store.read_manifest()
        saved = scan_config_from_dict(manifest.get("config", {}), f"{store.manifest_path}:config")
        _check_resume_matches(saved, config, resume)
        config = saved
        removed = store.remove_partial_captures()
        if removed:
            log.warning("removed interrupted partial captures: %s", ", ".join(removed))
    config = config or ScanConfig()
    kin = Kinematics()
    live = None
    with stages("setup"):
        if meshcat:
            from pydrake.geometry import Meshcat

            from robots.live_view import LiveView

            mc = Meshcat()
            print(f"Meshcat: {mc.web_url()}", flush=True)
        world = _setup_world(config, mc if meshcat else None)
        planner, stereo, X_FC = world.planner, world.stereo, world.X_FC
        if meshcat:
            live = LiveView(world.shown_cell, mc, kin.X_WF)
            live.show(world.robot.joint_positions() + world.joint_offsets_rad)
    q_home = world.robot.joint_positions()
    if resume is None:
        with stages("viewpoints"):
            plan = generate_viewpoints(
                config.views,
                config.scan_center_m,
                lambda vp: planner.reachable(vp, q_home),
                lambda q: planner.estimate_duration_s(q_home, q),
            )
        views = list(plan.views)
        plan_info = {
            "reachable_fraction": plan.reachable_fraction,
            "dropped_views": [{"direction": d.direction, "reason": d.reason} for d in plan.dropped],
        }
        store = CaptureStore.create(
            out_dir, _manifest(config, stereo, X_FC, views, plan_info), force
        )
        if world.sim is not None:
            _write_truth(store, world.sim)
    else:
        views = _views_from_manifest(manifest["viewpoints"], str(store.manifest_path))
        store.update_manifest(status="running")
    done = set(store.captured_indices())
    todo = [v for v in views if v.index not in done]
    with stages("ordering"):
        tour = plan_tour(q_home, todo, planner.estimate_duration_s)
    ordered = [todo[k] for k in tour.order]
    preferred = {todo[k].index: tour.option[k] for k in range(len(todo))}
    robot = _WatchedRobot(world.robot, live, world.joint_offsets_rad) if live else world.robot
    machine = DecisionMaker(
        planner,
        robot,
        world.camera,
        store,
        FixedViewList(ordered, preferred),
        len(views),
        kin.X_WF,
        MachineSettings(
            config.machine.capture_retries,
            config.machine.settle_tolerance_rad,
            config.machine.settle_timeout_s,
        ),
        process=_live_cloud(live, config, stereo, X_FC) if live else None,
    )
    total = len(views)
    if progress:
        progress(len(done), total)
        machine.on_view_done = lambda outcome: progress(len(store.captured_indices()), total)
    with stages("capture"), _interruptible(machine), _log_file(store.root / "scan.log"):
        summary = machine.run()
    status = "interrupted" if summary.state.value == "aborted" else "captured"
    skipped = [{"index": o.index, "reason": o.reason} for o in summary.skipped]
    store.update_manifest(status=status, skipped_views=skipped)

    def scan_report() -> dict:
        manifest = store.read_manifest()
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
            "estimated_tour_s": tour.cost_s,
            "wall_s": time.perf_counter() - wall0,
            "stage_s": {
                **stages.seconds,
                **{f"capture.{k}": v for k, v in summary.stage_s.items()},
            },
        }

    store.results_dir.mkdir(exist_ok=True)
    report_path = store.results_dir / "report.json"
    atomic_write_text(report_path, json.dumps(scan_report(), indent=2) + "\n")
    if config.reconstruct and status == "captured":
        with stages("reconstruction"):
            run_reconstruct(store.root)
        store.update_manifest(status="complete")
        report = json.loads(report_path.read_text())
        report.update(scan_report())
        atomic_write_text(report_path, json.dumps(report, indent=2) + "\n")
        write_summary(report, store.results_dir)
    report = json.loads(report_path.read_text())
    return ScanResult(store.root, report, summary)

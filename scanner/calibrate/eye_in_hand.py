"""`scanner calibrate` eye-in-hand, in simulation (or on a hardware driver): stations visited on
the planner's trajectories, captured into a calibration directory, then solved exactly like
recorded data."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from planners.planner import PlanFailure, Planner
from reconstruction.common.errors import ScannerError
from reconstruction.depth.camera_model import CameraModel
from robots.arms.default import arm_of
from robots.cache import cache_dir
from robots.drivers.connect import close_all, connect_robot
from robots.drivers.interfaces import (
    DepthCameraDriver,
    Hardware,
    RobotDriver,
    StereoCameraDriver,
    load_hardware,
)
from robots.models import camera_tool
from robots.models.calibration_board import (
    BoardFixture,
    board_fingerprint,
    write_board_obj,
)
from robots.models.kinematics import Kinematics
from robots.models.workcell import build_workcell
from robots.sensors import Sensor, sensor_named
from robots.sensors.registry import open_camera_of
from robots.simulation.cell import (
    Simulation,
    camera_at_reported_joints,
    create_simulation,
)
from robots.simulation.truth import save_truth
from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.offline import OfflineOptions, calibrate_directory
from scanner.calibrate.solve import CalibrationRun
from scanner.calibrate.stations import plan_stations
from scanner.configs.typed_yaml import to_dict
from scanner.scan_dir.captures import (
    Capture,
    CaptureStore,
    atomic_write_text,
    require_same_settings,
)

# Moves the arm to a configuration; False when it could not (the station is skipped).
MoveFn = Callable[[np.ndarray], bool]


@dataclass
class CalibrationWorld:
    """The cell with the board (simulated, or real through a driver), and the software's
    (nominal) view of it."""

    sim: Simulation | None  # None on hardware
    robot: RobotDriver
    camera: StereoCameraDriver | DepthCameraDriver
    stereo: CameraModel  # nominal: the stereo pair's, or the RGB-D device's
    X_FC: np.ndarray  # nominal
    X_WB: np.ndarray  # the configured board pose (in simulation also the true one)
    kinematics: Kinematics
    planner: Planner  # on the software's view of the cell (board, no object)

    def is_free(self, q: np.ndarray) -> bool:
        return self.planner.is_collision_free(q)


def _sensor(config: CalibrateConfig) -> Sensor:
    """The sensor kind the calibration's `sensor:` names."""
    return sensor_named(config.sensor, scanning=True)


def build_model(config: CalibrateConfig) -> CameraModel:
    """The nominal camera model of the calibration's sensor."""
    return _sensor(config).nominal_model(config)


def build_world(config: CalibrateConfig, extras=(), with_board: bool = True) -> CalibrationWorld:
    """The true simulated cell (board on its stand unless with_board is False, no object), or
    the hardware of `config.driver`, and a collision checker on the software's view of the cell."""
    stereo = build_model(config)
    X_FC = camera_tool.rig_X_FC(stereo.X_CR)
    fixtures = ()
    if with_board:
        directory = cache_dir() / "boards" / board_fingerprint(config.board)
        fixtures = (
            BoardFixture(config.board, config.placement, write_board_obj(config.board, directory)),
        )
    sim = None
    if config.driver:
        hardware = load_hardware(config.driver, config, _sensor(config))
    elif config.hardware is not None:
        hardware, sim = _configured_cell(config, stereo, X_FC, (*fixtures, *extras))
    else:
        sim = _board_cell(config, X_FC, (*fixtures, *extras))
        hardware = Hardware(sim.robot, sim.camera)
    arm = arm_of(config.robot)
    planner_cell = build_workcell(
        config.cell, None, X_FC, stereo.X_CR, arm, extras=fixtures, include_object=False
    )
    planner_config = replace(
        config.planner, cache_dir=config.planner.cache_dir or str(cache_dir() / "roadmaps")
    )
    return CalibrationWorld(
        sim,
        hardware.robot,
        hardware.camera,
        stereo,
        X_FC,
        config.placement.X_WB(config.board),
        Kinematics(arm),
        Planner(planner_cell, X_FC, stereo.X_CR, planner_config, arm),
    )


def _board_cell(config: CalibrateConfig, X_FC: np.ndarray, extras) -> Simulation:
    """The true simulated calibration cell (no object) with the configured sensor."""
    sensor = _sensor(config)
    stereo = config.camera.stereo_camera()
    return create_simulation(
        config.cell,
        None,
        config.error_model,
        stereo,
        X_FC,
        arm=arm_of(config.robot),
        extras=extras,
        rgbd=sensor.true_device(config),
        device=sensor.simulated_device,
    )


def _configured_cell(config: CalibrateConfig, stereo, X_FC, extras):
    """The hardware: section's robot link and camera (the simulated camera kind: the simulated
    board cell, rendered at the joints the link reports)."""
    robot = connect_robot(config.hardware.robot)
    try:
        if config.hardware.camera.kind == "simulated":
            sim = _board_cell(config, X_FC, extras)
            return Hardware(robot, camera_at_reported_joints(sim, robot)), sim
        camera = open_camera_of(config.hardware.camera, _sensor(config), stereo)
        return Hardware(robot, camera), None
    except BaseException:
        close_all(robot)
        raise


def planner_reachable(world: CalibrationWorld):
    """Collision-free IK solutions (with the planner's padding) for a look-at viewpoint."""
    q0 = world.robot.joint_positions()
    return lambda viewpoint: world.planner.reachable(viewpoint, q0)


class PlannedMover:
    """`move_to` through the motion planner: a validated, collision-free trajectory, executed."""

    def __init__(self, planner, robot) -> None:
        self._planner = planner
        self._robot = robot
        self.last_failure = ""

    def __call__(self, q: np.ndarray) -> bool:
        result = self._planner.plan(self._robot.joint_positions(), q)
        if not isinstance(result, PlanFailure):
            result = self._planner.executable(result, self._robot.motion)
        if isinstance(result, PlanFailure):
            self.last_failure = f"{result.reason}: {result.detail}"
            return False
        self._robot.execute(result)
        return True


def _check_resume_matches(manifest: dict, config: CalibrateConfig, where: Path) -> None:
    if manifest.get("kind") != "calibration" or "stations" not in manifest:
        raise ScannerError(f"{where}: not a calibration directory (scan.yaml has no stations)")
    wanted = {
        "board": to_dict(config.board),
        "placement": to_dict(config.placement),
        "camera": _sensor(config).model_to_dict(build_model(config)),
        "driver": config.driver,
    }
    require_same_settings(where, "calibration", {k: manifest.get(k) for k in wanted}, wanted)


def _station_list(manifest: dict, where: str) -> list[tuple[int, np.ndarray]]:
    try:
        return [(int(s["index"]), np.array(s["q_rad"], float)) for s in manifest["stations"]]
    except (KeyError, TypeError, ValueError) as e:
        raise ScannerError(f"{where}: malformed station list ({e})") from None


def run_eye_in_hand(
    config: CalibrateConfig,
    out_dir: Path,
    force: bool = False,
    move_to: MoveFn | None = None,
    reachable=None,
    progress: Callable[[int, int], None] | None = None,
    resume: bool = False,
) -> CalibrationRun:
    """Plan stations, capture each into a calibration directory, then calibrate from it.
    `resume`: continue the run in `out_dir` (its stations, the captures it lacks)."""

    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    if resume:
        store = CaptureStore.open(out_dir)
        manifest = store.read_manifest()
        _check_resume_matches(manifest, config, out_dir)
        stations = _station_list(manifest, str(store.manifest_path))
        store.remove_partial_captures()
        world = build_world(config)
    else:
        if out_dir.exists() and any(out_dir.iterdir()) and not force:
            raise ScannerError(
                f"{out_dir}: exists and is not empty; use --force to replace it, --resume "
                f"{out_dir} to finish its captures, or --offline {out_dir} to calibrate again "
                "from them"
            )
        world = build_world(config)
        store, stations = _start_run(config, world, out_dir, force, reachable)
    move_to = move_to or PlannedMover(world.planner, world.robot)
    done = set(store.captured_indices())
    skipped = []
    t_capture = time.perf_counter()
    for index, q_goal in stations:
        if index in done:
            continue
        if not move_to(q_goal):
            reason = getattr(move_to, "last_failure", "") or "no collision-free path"
            skipped.append({"index": index, "reason": reason})
            continue
        pair = world.camera.capture()
        q = world.robot.joint_positions()
        store.write_capture(Capture.of(index, len(stations), q, world.kinematics.X_WF(q), pair))
        if progress:
            progress(len(store.captured_indices()), len(stations))
    capture_s = time.perf_counter() - t_capture
    store.update_manifest(status="captured", skipped_stations=skipped)
    run = calibrate_directory(
        store.root,
        OfflineOptions(board=config.board, robot=config.robot),
        config.solver,
        extra_report={
            "stations_skipped": skipped,
            "capture_s": capture_s,
            "options": {
                "--stations": len(stations),
                "--seed": config.error_model.seed,
                "--driver": config.driver or "simulation",
            },
        },
    )
    run.report["calibrate_s"] = time.perf_counter() - t0
    atomic_write_text(run.results_dir / "report.json", json.dumps(run.report, indent=2) + "\n")
    return run


def _start_run(
    config: CalibrateConfig, world: CalibrationWorld, out_dir: Path, force: bool, reachable
) -> tuple[CaptureStore, list[tuple[int, np.ndarray]]]:
    """Plan the stations and create the calibration directory (manifest + truth in simulation)."""
    plan = plan_stations(
        config.stations,
        config.board,
        world.X_WB,
        world.stereo,
        world.X_FC,
        reachable or planner_reachable(world),
        world.robot.joint_positions(),
    )
    manifest = {
        "kind": "calibration",
        "board": to_dict(config.board),
        "placement": to_dict(config.placement),
        "camera": _sensor(config).model_to_dict(world.stereo),
        "X_FC_nominal": world.X_FC.tolist(),
        "pose_count": len(plan.stations),
        "stations": [
            {
                "index": s.index,
                "p_WM": list(s.viewpoint.p_WM),
                "p_WT": list(s.viewpoint.p_WT),
                "roll_rad": s.viewpoint.roll_rad,
                "q_rad": s.q.tolist(),
            }
            for s in plan.stations
        ],
        "stations_reachable": plan.reachable,
        "stations_candidates": plan.candidates,
        "driver": config.driver,
        "robot": config.robot,
    }
    store = CaptureStore.create(out_dir, manifest, force)
    if world.sim is not None:
        save_truth(world.sim.truth, store.root / "truth.yaml", {"X_WB": world.X_WB.tolist()})
    return store, [(s.index, s.q) for s in plan.stations]

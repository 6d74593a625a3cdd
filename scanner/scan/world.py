"""What a scan runs on: the simulated cell or a hardware driver, the planner on the software's
view of the cell, and the camera model and X_FC the software believes."""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from planners.planner import Planner
from reconstruction.calibration.file import load_calibration
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import transform_points
from reconstruction.depth.camera_model import CameraModel
from robots.arms.arm import Arm
from robots.arms.default import arm_of
from robots.cache import cache_dir
from robots.drivers.connect import close_all, connect_robot
from robots.drivers.interfaces import (
    DepthCameraDriver,
    Hardware,
    RobotDriver,
    StereoCameraDriver,
    TurntableDriver,
    load_hardware,
)
from robots.models.workcell import (
    Workcell,
    build_workcell,
    check_presentation,
    keep_out_radius_m,
)
from robots.sensors import Sensor, sensor_named
from robots.sensors.registry import open_camera_of
from robots.simulation.cell import (
    Simulation,
    camera_at_reported_joints,
    create_simulation,
    moved_object,
    rehang,
)
from scanner.configs.scan import ScanConfig


@dataclass(frozen=True, eq=False)
class ScanWorld:
    """The arm and camera a scan drives (simulated or a hardware driver's), the planner, and
    the camera model and X_FC the software believes (nominal or calibrated)."""

    robot: RobotDriver
    camera: StereoCameraDriver | DepthCameraDriver
    planner: Planner
    camera_model: CameraModel  # the stereo pair's or the RGB-D device's
    X_FC: np.ndarray
    sim: Simulation | None  # None on hardware: no truth
    shown_cell: Workcell | None  # the cell Meshcat shows (built with meshcat=)
    hardware: Hardware | None = None
    turntable: TurntableDriver | None = None  # a driver's (the simulated one: presentation's)

    def with_object_at(self, X_WO: np.ndarray, meshcat=None) -> ScanWorld:
        """The simulated world with the object at `X_WO` (a turntable turned it)."""
        sim = moved_object(self.sim, X_WO, meshcat)
        camera = sim.camera if self.hardware is None else camera_at_reported_joints(sim, self.robot)
        return replace(self, camera=camera, sim=sim, shown_cell=sim.workcell)

    def rehang(
        self, hanging: int, operator: str, request: dict | None = None, meshcat=None
    ) -> ScanWorld:
        """The world after the object was hung anew for pass `hanging`: the simulated operator
        turns it (`operator`), hardware asks the person. `request`: the scanner's instruction
        (`up_W`, `words`, `picture`), None for a fixed number of hangings."""
        up_W = None if request is None else np.asarray(request["up_W"], float)
        if self.sim is not None:
            sim = rehang(self.sim, hanging, meshcat, operator, up_W)
            # Over a robot link, the images follow the joints that link reports.
            camera = (
                sim.camera if self.hardware is None else camera_at_reported_joints(sim, self.robot)
            )
            return replace(self, camera=camera, sim=sim, shown_cell=sim.workcell)
        if self.hardware is None or self.hardware.request_rehang is None:
            raise ScannerError(
                "this driver cannot ask for a re-hang (Hardware.request_rehang is None): scan "
                "one hanging per run (hangings: 1) and combine the scans with scanner merge"
            )
        if request is not None:
            self.hardware.request_rehang(request["words"])
        else:
            self.hardware.request_rehang(
                f"hanging {hanging + 1}: hang the object from another point, turned by 90-180 "
                "deg (upside down is best), then confirm"
            )
        return self

    @property
    def joint_offsets_rad(self) -> np.ndarray:
        return self.sim.truth.joint_offsets_rad if self.sim else np.zeros(self.arm.joint_count)

    @property
    def arm(self) -> Arm:
        return self.planner.arm


def software_kinematics(config: ScanConfig):
    """X_WF(q) as the software computes the flange pose from the joints the robot reports: the
    configured arm as drawn, or as the calibration file's robot correction found it (joint zero
    offsets, link lengths; `scanner calibrate --robot-offsets`), so that every capture's pose
    carries the arm's own errors as the calibration measured them."""
    from robots.models.kinematics import Kinematics, corrected_kinematics

    correction = None
    if config.calibration_file:
        correction = load_calibration(Path(config.calibration_file)).robot
    if correction is None:
        return Kinematics(arm_of(config.robot)).X_WF
    return corrected_kinematics(arm_of(config.robot), correction, "calibration_file")


def software_camera(config: ScanConfig) -> tuple[CameraModel, np.ndarray]:
    """The camera model and X_FC the software believes: the calibration file's, else the
    sensor's nominal ones (robots.sensors: an RGB-D device keeps its own depth camera and
    extrinsics; a calibration gives X_FC and its colour camera)."""
    sensor = sensor_of_config(config)
    model = sensor.nominal_model(config)
    X_FC = sensor.nominal_X_FC(model)
    if not config.calibration_file:
        return model, X_FC
    calibration = load_calibration(Path(config.calibration_file))
    return sensor.calibrated_model(model, calibration, config.calibration_file), calibration.X_FC


def sensor_of_config(config: ScanConfig) -> Sensor:
    """The sensor kind the configuration's `sensor:` names."""
    return sensor_named(config.sensor, scanning=True)


def check_reach(config: ScanConfig, model: CameraModel) -> None:
    """Refuse, before moving, a standoff at which the sensor cannot measure the object."""
    radius = keep_out_radius_m(config.cell)
    if config.views.radius_m <= radius:
        raise ScannerError(
            f"views.radius_m: {config.views.radius_m} m puts the camera inside the object's "
            f"bounding sphere ({radius:.3f} m for a {config.cell.object_size_m} m object)"
        )
    sensor_of_config(config).check_reach(model, config.views.radius_m, radius)


def simulated_cell(
    config: ScanConfig, meshcat=None, hanging: int = 0, X_WO: np.ndarray | None = None
) -> Simulation:
    """The true simulated world of a scan: its object, error model and sensor design
    (`X_WO`: where the operator hung the object for this hanging, when it is known)."""
    sensor = sensor_of_config(config)
    design = config.camera.stereo_camera()
    return create_simulation(
        config.cell,
        config.object,
        config.error_model,
        design,
        sensor.nominal_X_FC(sensor.nominal_model(config)),
        arm=arm_of(config.robot),
        meshcat=meshcat,
        hanging=hanging,
        X_WO=X_WO,
        rgbd=sensor.true_device(config),
        device=sensor.simulated_device,
        presentation=config.presentation,
    )


def setup_world(
    config: ScanConfig, meshcat=None, hanging: int = 0, X_WO: np.ndarray | None = None
) -> ScanWorld:
    """The simulated cell (or the configured driver's hardware) and a planner on the software's
    view of the cell, after checking that the stereo camera can measure at the standoff and
    that the cell can re-hang the object when the scan may ask for it."""
    model, X_FC = software_camera(config)
    check_reach(config, model)
    check_presentation(config.presentation)
    sim = hardware = None
    if config.driver or config.hardware is not None:
        if config.driver:
            hardware = load_hardware(config.driver, config, sensor_of_config(config))
        else:
            hardware, sim = connect_cell(config, model, meshcat, hanging, X_WO)
        if config.auto_hangings and hardware.request_rehang is None and sim is None:
            raise ScannerError(
                "hangings: 'auto' needs a driver that can ask for a re-hang "
                "(Hardware.request_rehang); this one cannot: scan with --hangings 1 and "
                "combine scans with scanner merge"
            )
        if config.presentation == "turntable":
            from scanner.scan.presentation.turntable_check import check_turntable

            check_turntable(hardware.turntable)
    else:
        sim = simulated_cell(config, meshcat, hanging, X_WO)
    arm = arm_of(config.robot)
    planner_cell = build_workcell(
        config.cell,
        None,
        X_FC,
        model.X_CR,
        arm,
        meshcat=meshcat if hardware else None,
        presentation=config.presentation,
    )
    # Scans always cache the roadmap (a second scan of the same cell starts at once).
    roadmaps = config.planner.cache_dir or str(cache_dir() / "roadmaps")
    planner = Planner(
        planner_cell, X_FC, model.X_CR, replace(config.planner, cache_dir=roadmaps), arm
    )
    if hardware:
        calibrated = model if config.calibration_file else None
        model = sensor_of_config(config).driver_model(hardware.camera, model, calibrated)
        shown = sim.workcell if sim is not None else planner_cell
        return ScanWorld(
            hardware.robot,
            hardware.camera,
            planner,
            model,
            X_FC,
            sim,
            shown,
            hardware,
            hardware.turntable,
        )
    return ScanWorld(sim.robot, sim.camera, planner, model, X_FC, sim, sim.workcell)


def connect_cell(
    config: ScanConfig, model: CameraModel, meshcat, hanging: int, X_WO: np.ndarray | None
) -> tuple[Hardware, Simulation | None]:
    """The `hardware:` section's robot link and camera (and, for the simulated camera, the
    simulated cell it renders: its truth then judges the result)."""
    robot = connect_robot(config.hardware.robot)
    try:
        if config.hardware.camera.kind == "simulated":
            sim = simulated_cell(config, meshcat, hanging, X_WO)
            return Hardware(robot, camera_at_reported_joints(sim, robot)), sim
        camera = open_camera_of(config.hardware.camera, sensor_of_config(config), model)
    except BaseException:
        close_all(robot)
        raise
    rehang = ask_operator if sys.stdin.isatty() else None
    return Hardware(robot, camera, rehang), None


def ask_operator(message: str) -> None:
    """A re-hang request on the console: the operator re-hangs, then presses Enter."""
    input(f"{message}\nPress Enter when the object hangs still: ")


class WatchedRobot(RobotDriver):
    """Plays every executed trajectory in Meshcat before the arm takes it."""

    def __init__(self, robot: RobotDriver, live, joint_offsets_rad: np.ndarray) -> None:
        self._robot, self._live, self._offsets = robot, live, joint_offsets_rad
        self.motion = robot.motion

    def joint_positions(self) -> np.ndarray:
        return self._robot.joint_positions()

    def execute(self, trajectory) -> None:
        self._live.play(trajectory, self._offsets)
        self._robot.execute(trajectory)


def live_cloud(live, config: ScanConfig, model: CameraModel, X_FC: np.ndarray):
    """The PROCESS state with --meshcat: each capture's cloud (every 4th pixel) joins the
    growing cloud in Meshcat, placed by the kinematic pose and the nominal X_FC."""
    centre = np.array(config.scan_center_m)
    radius = keep_out_radius_m(config.cell)
    sensor = sensor_of_config(config)
    prepared = sensor.prepare(model)
    params = config.processing.stereo

    def process(capture) -> None:
        X_WC = capture.X_WF @ X_FC
        c = sensor.cloud(prepared, capture, X_WC, centre, radius, params, step_px=4)
        live.add_cloud(f"{capture.pose_index:04d}", transform_points(X_WC, c.points_C), c.colors)

    return process

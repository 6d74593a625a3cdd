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
from reconstruction.stereo.camera_model import StereoCamera
from reconstruction.stereo.cloud import view_cloud
from reconstruction.stereo.params import disparity_window, object_depth_window
from reconstruction.stereo.rectification import compute_rectification
from robots.drivers.connect import close_all, connect_robot, open_camera
from robots.drivers.interfaces import Hardware, RobotDriver, StereoCameraDriver, load_hardware
from robots.models import camera_tool
from robots.models.workcell import Workcell, build_workcell, keep_out_radius_m
from robots.simulation.cell import (
    Simulation,
    cache_dir,
    camera_at_reported_joints,
    create_simulation,
    rehang,
)
from scanner.configs.scan import ScanConfig


@dataclass(frozen=True, eq=False)
class ScanWorld:
    """The arm and camera a scan drives (simulated or a hardware driver's), the planner, and
    the camera model and X_FC the software believes (nominal or calibrated)."""

    robot: RobotDriver
    camera: StereoCameraDriver
    planner: Planner
    stereo: StereoCamera
    X_FC: np.ndarray
    sim: Simulation | None  # None on hardware: no truth
    shown_cell: Workcell | None  # the cell Meshcat shows (built with meshcat=)
    hardware: Hardware | None = None

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
        return self.sim.truth.joint_offsets_rad if self.sim else np.zeros(6)


def software_camera(config: ScanConfig) -> tuple[StereoCamera, np.ndarray]:
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


def check_stereo_reach(config: ScanConfig, stereo: StereoCamera) -> None:
    """Refuse, before moving, a standoff at which the stereo camera cannot measure the object.

    Left-image columns below min_disparity + num_disparities have no match in the right image;
    the remaining band must hold at least half the object's image (its bounding sphere's image
    radius f r / d), else most of the object is never measured.
    """
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


def simulated_cell(
    config: ScanConfig, meshcat=None, hanging: int = 0, X_WO: np.ndarray | None = None
) -> Simulation:
    """The true simulated world of a scan: its object, error model and camera design
    (`X_WO`: where the operator hung the object for this hanging, when it is known)."""
    design = config.camera.stereo_camera()
    return create_simulation(
        config.cell,
        config.object,
        config.error_model,
        design,
        camera_tool.nominal_X_FC(design.baseline_m),
        meshcat=meshcat,
        hanging=hanging,
        X_WO=X_WO,
    )


def setup_world(
    config: ScanConfig, meshcat=None, hanging: int = 0, X_WO: np.ndarray | None = None
) -> ScanWorld:
    """The simulated cell (or the configured driver's hardware) and a planner on the software's
    view of the cell, after checking that the stereo camera can measure at the standoff and
    that the cell can re-hang the object when the scan may ask for it."""
    stereo, X_FC = software_camera(config)
    check_stereo_reach(config, stereo)
    sim = hardware = None
    if config.driver or config.hardware is not None:
        if config.driver:
            hardware = load_hardware(config.driver, config)
        else:
            hardware, sim = connect_cell(config, stereo, meshcat, hanging, X_WO)
        if config.auto_hangings and hardware.request_rehang is None and sim is None:
            raise ScannerError(
                "hangings: 'auto' needs a driver that can ask for a re-hang "
                "(Hardware.request_rehang); this one cannot: scan with --hangings 1 and "
                "combine scans with scanner merge"
            )
    else:
        sim = simulated_cell(config, meshcat, hanging, X_WO)
    planner_cell = build_workcell(
        config.cell, None, X_FC, stereo.X_CR, meshcat=meshcat if hardware else None
    )
    # Scans always cache the roadmap (a second scan of the same cell starts at once).
    roadmaps = config.planner.cache_dir or str(cache_dir() / "roadmaps")
    planner = Planner(planner_cell, X_FC, stereo.X_CR, replace(config.planner, cache_dir=roadmaps))
    if hardware:
        shown = sim.workcell if sim is not None else planner_cell
        return ScanWorld(
            hardware.robot, hardware.camera, planner, stereo, X_FC, sim, shown, hardware
        )
    return ScanWorld(sim.robot, sim.camera, planner, stereo, X_FC, sim, sim.workcell)


def connect_cell(
    config: ScanConfig, stereo: StereoCamera, meshcat, hanging: int, X_WO: np.ndarray | None
) -> tuple[Hardware, Simulation | None]:
    """The `hardware:` section's robot link and camera (and, for the simulated camera, the
    simulated cell it renders: its truth then judges the result)."""
    robot = connect_robot(config.hardware.robot)
    try:
        if config.hardware.camera.kind == "simulated":
            sim = simulated_cell(config, meshcat, hanging, X_WO)
            return Hardware(robot, camera_at_reported_joints(sim, robot)), sim
        camera = open_camera(config.hardware.camera, stereo.image_size)
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


def live_cloud(live, config: ScanConfig, stereo: StereoCamera, X_FC: np.ndarray):
    """The PROCESS state with --meshcat: each capture's stereo cloud (every 4th pixel) joins the
    growing cloud in Meshcat, placed by the kinematic pose and the nominal X_FC."""
    rect = compute_rectification(stereo)
    params = replace(config.processing.stereo, subsample_step_px=4)
    centre = np.array(config.scan_center_m)
    radius = keep_out_radius_m(config.cell)

    def process(capture) -> None:
        X_WC = capture.X_WF @ X_FC
        cloud = view_cloud(rect, capture.left, capture.right, X_WC, centre, radius, params)
        p_W = transform_points(X_WC, cloud.points_C)
        live.add_cloud(f"{capture.pose_index:04d}", p_W, cloud.colors)

    return process

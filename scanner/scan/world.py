"""What a scan runs on: the simulated cell or a hardware driver, the planner on the software's
view of the cell, and the camera model and X_FC the software believes."""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from planners.planner import Planner
from reconstruction.calibration.file import calibrated_model, load_calibration
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import transform_points
from reconstruction.depth.camera_model import CameraModel, RgbdCamera
from reconstruction.depth.cloud import view_rgbd_cloud
from reconstruction.stereo.camera_model import StereoCamera
from reconstruction.stereo.cloud import view_cloud
from reconstruction.stereo.params import disparity_window, object_depth_window
from reconstruction.stereo.rectification import compute_rectification
from robots.arms.arm import Arm
from robots.arms.default import arm_of
from robots.cache import cache_dir
from robots.drivers.connect import close_all, connect_robot, open_camera, open_depth_camera
from robots.drivers.interfaces import (
    DepthCameraDriver,
    Hardware,
    RobotDriver,
    StereoCameraDriver,
    load_hardware,
)
from robots.models import camera_tool
from robots.models.workcell import Workcell, build_workcell, keep_out_radius_m
from robots.simulation.cell import (
    Simulation,
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
    camera: StereoCameraDriver | DepthCameraDriver
    planner: Planner
    camera_model: CameraModel  # the stereo pair's or the RGB-D device's
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
    """The camera model and X_FC the software believes: the calibration file's, else nominal.
    An RGB-D device keeps its own depth camera and extrinsics; a calibration gives X_FC and
    its colour camera."""
    if config.sensor == "rgbd":
        model = config.rgbd.rgbd_camera()
        X_FC = camera_tool.rig_X_FC(model.X_CR)
    else:
        model = config.camera.stereo_camera()
        X_FC = camera_tool.nominal_X_FC(model.baseline_m)
    if not config.calibration_file:
        return model, X_FC
    calibration = load_calibration(Path(config.calibration_file))
    return calibrated_model(model, calibration, config.calibration_file), calibration.X_FC


def check_reach(config: ScanConfig, model: CameraModel) -> None:
    """Refuse, before moving, a standoff at which the sensor cannot measure the object."""
    radius = keep_out_radius_m(config.cell)
    if config.views.radius_m <= radius:
        raise ScannerError(
            f"views.radius_m: {config.views.radius_m} m puts the camera inside the object's "
            f"bounding sphere ({radius:.3f} m for a {config.cell.object_size_m} m object)"
        )
    if isinstance(model, RgbdCamera):
        z_min, z_max = object_depth_window(config.views.radius_m, radius)
        if z_min < model.min_depth_m or z_max > model.max_depth_m:
            raise ScannerError(
                f"views.radius_m: at {config.views.radius_m} m the object spans depths "
                f"{z_min:.3f}-{z_max:.3f} m; the depth camera measures "
                f"{model.min_depth_m}-{model.max_depth_m} m (rgbd.min_depth_m, max_depth_m)"
            )
        return
    check_stereo_reach(config, model)


def check_stereo_reach(config: ScanConfig, stereo: StereoCamera) -> None:
    """Refuse, before moving, a standoff at which the stereo camera cannot measure the object.

    Left-image columns below min_disparity + num_disparities have no match in the right image;
    the remaining band must hold at least half the object's image (its bounding sphere's image
    radius f r / d), else most of the object is never measured.
    """
    radius = keep_out_radius_m(config.cell)
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
    """The true simulated world of a scan: its object, error model and sensor design
    (`X_WO`: where the operator hung the object for this hanging, when it is known)."""
    design = config.camera.stereo_camera()
    rgbd = config.rgbd.rgbd_camera() if config.sensor == "rgbd" else None
    X_FC = camera_tool.rig_X_FC(rgbd.X_CR) if rgbd else camera_tool.nominal_X_FC(design.baseline_m)
    return create_simulation(
        config.cell,
        config.object,
        config.error_model,
        design,
        X_FC,
        arm=arm_of(config.robot),
        meshcat=meshcat,
        hanging=hanging,
        X_WO=X_WO,
        rgbd=rgbd,
    )


def setup_world(
    config: ScanConfig, meshcat=None, hanging: int = 0, X_WO: np.ndarray | None = None
) -> ScanWorld:
    """The simulated cell (or the configured driver's hardware) and a planner on the software's
    view of the cell, after checking that the stereo camera can measure at the standoff and
    that the cell can re-hang the object when the scan may ask for it."""
    model, X_FC = software_camera(config)
    check_reach(config, model)
    sim = hardware = None
    if config.driver or config.hardware is not None:
        if config.driver:
            hardware = load_hardware(config.driver, config)
        else:
            hardware, sim = connect_cell(config, model, meshcat, hanging, X_WO)
        if config.auto_hangings and hardware.request_rehang is None and sim is None:
            raise ScannerError(
                "hangings: 'auto' needs a driver that can ask for a re-hang "
                "(Hardware.request_rehang); this one cannot: scan with --hangings 1 and "
                "combine scans with scanner merge"
            )
    else:
        sim = simulated_cell(config, meshcat, hanging, X_WO)
    arm = arm_of(config.robot)
    planner_cell = build_workcell(
        config.cell, None, X_FC, model.X_CR, arm, meshcat=meshcat if hardware else None
    )
    # Scans always cache the roadmap (a second scan of the same cell starts at once).
    roadmaps = config.planner.cache_dir or str(cache_dir() / "roadmaps")
    planner = Planner(
        planner_cell, X_FC, model.X_CR, replace(config.planner, cache_dir=roadmaps), arm
    )
    if hardware:
        device_model = getattr(hardware.camera, "rgbd_camera", None)
        if device_model is not None:
            calibrated = model if config.calibration_file else None
            model = device_model_as_calibrated(device_model(), calibrated)
        shown = sim.workcell if sim is not None else planner_cell
        return ScanWorld(
            hardware.robot, hardware.camera, planner, model, X_FC, sim, shown, hardware
        )
    return ScanWorld(sim.robot, sim.camera, planner, model, X_FC, sim, sim.workcell)


def device_model_as_calibrated(device: RgbdCamera, calibrated: RgbdCamera | None) -> RgbdCamera:
    """A real depth camera's model is what the device reports (its intrinsics, depth unit,
    depth aligned to colour); a calibration adds its depth correction and its colour
    intrinsics (the aligned depth lies on the colour grid)."""
    if calibrated is None:
        return device
    model = replace(device, depth_correction=calibrated.depth_correction)
    if calibrated.image_size != device.image_size:
        raise ScannerError(
            f"calibration_file: calibrated for {calibrated.image_size[0]}x"
            f"{calibrated.image_size[1]} colour images, the camera delivers "
            f"{device.image_size[0]}x{device.image_size[1]}"
        )
    return replace(model, color=calibrated.color, depth=calibrated.color)


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
        kind = config.hardware.camera.kind
        wanted = "rgbd" if kind == "realsense" else "stereo"
        if config.sensor != wanted:
            what = "an RGB-D camera (sensor: rgbd)" if wanted == "rgbd" else "a stereo camera"
            raise ScannerError(
                f"hardware.camera.kind: '{kind}' is {what}; the configuration's sensor is "
                f"{config.sensor}"
            )
        if kind == "realsense":
            camera = open_depth_camera(config.hardware.camera)
        else:
            camera = open_camera(config.hardware.camera, model.image_size)
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
    if isinstance(model, RgbdCamera):

        def cloud_of(capture, X_WC):
            c = view_rgbd_cloud(model, capture.depth, capture.left, X_WC, centre, radius, 4)
            return c.points_C, c.colors
    else:
        rect = compute_rectification(model)
        params = replace(config.processing.stereo, subsample_step_px=4)

        def cloud_of(capture, X_WC):
            c = view_cloud(rect, capture.left, capture.right, X_WC, centre, radius, params)
            return c.points_C, c.colors

    def process(capture) -> None:
        X_WC = capture.X_WF @ X_FC
        points_C, colors = cloud_of(capture, X_WC)
        live.add_cloud(f"{capture.pose_index:04d}", transform_points(X_WC, points_C), colors)

    return process

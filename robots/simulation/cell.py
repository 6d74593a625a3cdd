"""One simulated world: true work cell with renderer, truth, robot and stereo camera."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from reconstruction.depth.camera_model import RgbdCamera
from reconstruction.stereo.camera_model import StereoCamera, default_stereo_camera
from robots.arms.arm import Arm
from robots.arms.default import DEFAULT_ARM
from robots.cache import cache_dir
from robots.drivers.interfaces import RobotDriver
from robots.models import camera_tool
from robots.models.objects import ObjectMesh, mesh_fingerprint, resolve_object, write_textured_obj
from robots.models.workcell import Workcell, WorkcellConfig, build_workcell, placed_object
from robots.simulation.operator import hung_pose, rehung_pose
from robots.simulation.robot import SimulatedRobot
from robots.simulation.stereo_camera import SimulatedStereoCamera
from robots.simulation.truth import ErrorModel, Truth, sample_truth

# The default arm's home (each arm names its own: Arm.home_q).
HOME_Q = DEFAULT_ARM.home_q


def textured_object(mesh: ObjectMesh, texture_seed: int = 0) -> Path:
    """The object's textured OBJ in the cache (content-addressed, written once)."""
    directory = cache_dir() / "objects" / f"{mesh.name}-{mesh_fingerprint(mesh, texture_seed)}"
    return write_textured_obj(mesh, directory, texture_seed)


def object_vertices_W(mesh: ObjectMesh, X_WO: np.ndarray) -> np.ndarray:
    return mesh.vertices @ X_WO[:3, :3].T + X_WO[:3, 3]


@dataclass
class Simulation:
    workcell: Workcell
    truth: Truth
    robot: SimulatedRobot
    camera: SimulatedStereoCamera  # or a SimulatedDepthCamera when the tool carries one
    object_mesh: ObjectMesh | None
    # (workcell, truth, true_joint_positions) -> the tool's camera: a sensor kind's simulated
    # device (robots.sensors), kept for the cells rebuilt after a re-hang.
    device: Callable | None = None


def create_simulation(
    cell: WorkcellConfig,
    object_spec: str | None,
    error_model: ErrorModel = ErrorModel(),
    stereo: StereoCamera | None = None,
    X_FC_nominal: np.ndarray | None = None,
    arm: Arm = DEFAULT_ARM,
    q0: np.ndarray | None = None,
    meshcat=None,
    extras: Sequence[Callable] = (),
    hanging: int = 0,
    X_WO: np.ndarray | None = None,
    rgbd: RgbdCamera | None = None,
    presentation: str = "hanging",
    device: Callable | None = None,
) -> Simulation:
    """Build the true world for `object_spec` (built-in name or mesh path) and its error model.

    `object_spec=None` builds the cell without an object (calibration); `extras` are passed to
    `build_workcell` (e.g. a calibration board). `rgbd`: the tool carries this depth camera
    (X_FC_nominal then places its colour camera) instead of the stereo pair. `arm` starts at
    `q0` (None: its home). `presentation`: the object hangs from the rod ("hanging"), stands
    on the turntable ("turntable", at its zero angle) or lies on the table ("table"), settled on
    the face underneath as configured unless `X_WO` is given.
    `device(workcell, truth, true_joint_positions)`: the tool's simulated camera (a sensor
    kind's, robots.sensors; None: the stereo pair, or the depth camera with `rgbd`).
    """
    stereo = stereo or default_stereo_camera()
    if X_FC_nominal is None:
        X_FC_nominal = camera_tool.nominal_X_FC(stereo.baseline_m)
    mesh = None if object_spec is None else resolve_object(object_spec, cell.object_size_m)
    if X_WO is None and presentation != "hanging" and mesh is not None:
        from robots.simulation.laying import first_lying_pose

        # Put down on a table or a turntable's disc, it settles on the face underneath.
        X_WO = first_lying_pose(cell, mesh)
    if X_WO is None:  # else the pose the operator hung it in (a resumed scan's truth file)
        X_WO = hung_pose(cell.X_WO, error_model.seed, hanging)
    truth = sample_truth(error_model, X_FC_nominal, stereo, X_WO, rgbd, arm.joint_count)
    sim_robot = SimulatedRobot(arm, truth.joint_offsets_rad, arm.home_q if q0 is None else q0)
    return _assemble(cell, mesh, truth, sim_robot, meshcat, extras, presentation, device)


def _assemble(
    cell: WorkcellConfig,
    mesh: ObjectMesh | None,
    truth: Truth,
    sim_robot: SimulatedRobot,
    meshcat=None,
    extras: Sequence[Callable] = (),
    presentation: str = "hanging",
    device: Callable | None = None,
) -> Simulation:
    obj = None
    if mesh is not None:
        obj_path = textured_object(mesh, truth.seed)
        obj = placed_object(obj_path, mesh.vertices, mesh.triangles, truth.X_WO[:3, :3])
    workcell = build_workcell(
        cell,
        obj,
        truth.X_FC,
        (truth.rgbd or truth.stereo).X_CR,
        sim_robot.arm,
        renderer=True,
        meshcat=meshcat,
        extras=extras,
        include_object=mesh is not None,
        X_WO=truth.X_WO,
        presentation=presentation,
    )
    camera = (device or simulated_camera)(workcell, truth, sim_robot.true_joint_positions)
    return Simulation(workcell, truth, sim_robot, camera, mesh, device)


def simulated_camera(workcell: Workcell, truth: Truth, true_joint_positions):
    """The tool's simulated sensor: the stereo pair, or the depth camera when the truth has one."""
    if truth.rgbd is not None:
        from robots.simulation.depth_camera import SimulatedDepthCamera

        return SimulatedDepthCamera(
            workcell, truth, true_joint_positions, truth.rgbd.depth_baseline_m
        )
    return SimulatedStereoCamera(workcell, truth, true_joint_positions)


def camera_at_reported_joints(sim: Simulation, robot: RobotDriver):
    """The simulated cell's camera placed by the joints `robot` reports (plus the simulated
    encoder offsets), not by the simulator's own arm: with the controller emulator, the images
    follow the arm the wire reports."""
    offsets = sim.truth.joint_offsets_rad
    device = sim.device or simulated_camera
    return device(sim.workcell, sim.truth, lambda: robot.joint_positions() + offsets)


def rehang(
    sim: Simulation, hanging: int, meshcat=None, operator: str = "random", up_W=None
) -> Simulation:
    """The same cell, robot (where it stands) and errors with the object hung anew by the
    operator (robots.simulation.operator), asked to bring `up_W` to the top (None: no
    instruction)."""
    cell = sim.workcell.config
    X_WO = rehung_pose(sim.truth.X_WO, cell.X_WO, sim.truth.seed, hanging, operator, up_W)
    truth = replace(sim.truth, X_WO=X_WO)
    presentation = sim.workcell.presentation
    return _assemble(
        cell, sim.object_mesh, truth, sim.robot, meshcat, (), presentation, device=sim.device
    )


def moved_object(sim: Simulation, X_WO: np.ndarray, meshcat=None) -> Simulation:
    """The same cell, robot (where it stands) and errors with the object at `X_WO` (a
    turntable turned it)."""
    truth = replace(sim.truth, X_WO=np.asarray(X_WO, float))
    cell, presentation = sim.workcell.config, sim.workcell.presentation
    return _assemble(
        cell, sim.object_mesh, truth, sim.robot, meshcat, (), presentation, device=sim.device
    )

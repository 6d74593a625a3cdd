"""An arm's model in Drake: the file of an arm file parsed into a MultibodyPlant, its root link
welded at the base pose X_WB, with the joint chain from base to flange and its limits.

xacro files are expanded first (the PyPI `xacro` package, ROS's own processor), with `$(find pkg)`
answered from the arm file's package map, so a ROS description works without a ROS install. Meshes
Drake cannot read are converted in the cache (robots/arms/meshes.py) and the model's references
point there.
"""

from __future__ import annotations

import contextlib
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, MultibodyPlant
from pydrake.multibody.tree import Frame
from pydrake.systems.framework import Diagram, DiagramBuilder

from reconstruction.common.errors import ScannerError
from robots.arms.meshes import drake_readable

if TYPE_CHECKING:
    from robots.arms.arm_file import ArmFile

# A URDF <mesh filename="..."/> and an SDF <mesh><uri>...</uri>; rewritten as text, because an XML
# round trip would rename the `drake:` namespace prefixes that Drake's parser matches literally.
_URDF_MESH = re.compile(r"""(<mesh\b[^>]*?\bfilename\s*=\s*)(["'])(.*?)\2""", re.DOTALL)
_SDF_MESH = re.compile(r"(<mesh>\s*<uri>\s*)(.*?)(\s*</uri>)", re.DOTALL)


@dataclass(frozen=True, eq=False)
class ArmPlant:
    """The parsed arm. Arrays are per chain joint, base to flange, read-only: position limits
    (rad or m), velocity (rad/s or m/s), acceleration (rad/s^2 or m/s^2); `revolute` marks the
    joints whose position is an angle. `diagram` owns the plant and its SceneGraph."""

    diagram: Diagram
    plant: MultibodyPlant
    flange_frame: Frame
    joint_names: tuple[str, ...]
    position_starts: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    revolute: np.ndarray

    def plant_positions(self, q: np.ndarray) -> np.ndarray:
        """The plant's position vector of chain positions `q`."""
        q_plant = np.zeros(self.plant.num_positions())
        q_plant[self.position_starts] = q
        return q_plant

    def X_WF(self, q: np.ndarray) -> RigidTransform:
        """The flange pose in the world at joint positions `q` (chain order)."""
        context = self.plant.CreateDefaultContext()
        self.plant.SetPositions(context, self.plant_positions(np.asarray(q, float)))
        return self.flange_frame.CalcPoseInWorld(context)


_XACRO_FIND_LOCK = threading.Lock()


@contextlib.contextmanager
def _finds_from(packages: dict[str, Path], arm_file: ArmFile):
    """xacro's `$(find pkg)` answered from the package map while expanding (xacro asks
    ament_index otherwise, which needs a ROS 2 install)."""
    import xacro.substitution_args as substitution_args

    def find(package: str) -> str:
        if package not in packages:
            raise ScannerError(
                f"{arm_file.path}: packages: expected a folder for package {package!r}, which "
                f"{arm_file.model.name} uses"
            )
        return str(packages[package])

    # xacro keeps the lookup in a module global: one expansion at a time may replace it.
    with _XACRO_FIND_LOCK:
        original = substitution_args._eval_find
        substitution_args._eval_find = find
        try:
            yield
        finally:
            substitution_args._eval_find = original


def _expand_xacro(arm_file: ArmFile) -> str:
    import xacro

    with _finds_from(dict(arm_file.packages), arm_file):
        try:
            return xacro.process_file(str(arm_file.model)).toprettyxml(indent="  ")
        except ScannerError:
            raise
        except Exception as e:
            detail = " ".join(str(e).split())
            raise ScannerError(
                f"{arm_file.path}: model: xacro could not expand {arm_file.model} ({detail})"
            ) from None


def _mesh_path(uri: str, arm_file: ArmFile) -> Path:
    packages = dict(arm_file.packages)
    if uri.startswith("package://"):
        package, _, rest = uri[len("package://") :].partition("/")
        if package not in packages:
            raise ScannerError(
                f"{arm_file.path}: packages: expected a folder for package {package!r}, which "
                f"{arm_file.model.name} uses"
            )
        path = packages[package] / rest
    else:
        path = arm_file.model.parent / uri.removeprefix("file://")  # absolute stays absolute
    if not path.is_file():
        raise ScannerError(
            f"{arm_file.path}: model: mesh {uri} of {arm_file.model.name} resolved to {path}, "
            "which does not exist"
        )
    return path


def model_text(arm_file: ArmFile) -> tuple[str, str]:
    """(text, "urdf" or "sdf") of the arm's model, xacro expanded and every mesh reference an
    absolute path to a file Drake reads."""
    name = arm_file.model.name
    text = _expand_xacro(arm_file) if name.endswith(".xacro") else arm_file.model.read_text()
    kind = "sdf" if name.endswith(".sdf") else "urdf"

    def absolute(uri: str) -> str:
        if uri.startswith("model://"):
            return uri
        return drake_readable(_mesh_path(uri.strip(), arm_file)).as_uri()

    if kind == "urdf":
        text = _URDF_MESH.sub(lambda m: f"{m[1]}{m[2]}{absolute(m[3])}{m[2]}", text)
    else:
        text = _SDF_MESH.sub(lambda m: f"{m[1]}{absolute(m[2])}{m[3]}", text)
    return text, kind


def _root_body(plant: MultibodyPlant, instance, arm_file: ArmFile):
    children = {plant.get_joint(j).child_body().index() for j in plant.GetJointIndices(instance)}
    roots = [b for b in plant.GetBodyIndices(instance) if b not in children]
    if len(roots) != 1:
        names = ", ".join(plant.get_body(b).name() for b in roots) or "none (fixed to the world)"
        raise ScannerError(
            f"{arm_file.path}: model: expected one root link to place at base_pose, "
            f"{arm_file.model.name} has {names}"
        )
    return plant.get_body(roots[0])


def _chain(plant: MultibodyPlant, instance, flange_body, arm_file: ArmFile) -> list:
    """The movable joints from the root to the flange body, base first."""
    by_child = {plant.get_joint(j).child_body().index(): plant.get_joint(j) for j in
                plant.GetJointIndices(instance)}  # fmt: skip
    chain, body = [], flange_body
    while body.index() in by_child:
        joint = by_child[body.index()]
        if joint.num_positions() > 0:
            chain.append(joint)
        body = joint.parent_body()
    chain.reverse()
    on_chain = {j.index() for j in chain}
    for j in plant.GetJointIndices(instance):
        joint = plant.get_joint(j)
        if joint.num_positions() > 0 and j not in on_chain:
            raise ScannerError(
                f"{arm_file.path}: flange_link: expected every movable joint between the base and "
                f"{arm_file.flange_link!r}, {joint.name()} is not"
            )
        if j in on_chain and joint.type_name() not in ("revolute", "prismatic"):
            raise ScannerError(
                f"{arm_file.path}: model: expected revolute or prismatic joints, "
                f"{joint.name()} is {joint.type_name()}"
            )
    return chain


def _limit(model_value: float, fill: float | None, arm_file: ArmFile, joint: str, key: str):
    """The model's limit where it has one (finite), else the arm file's."""
    if np.isfinite(model_value) and (key.startswith(("lower", "upper")) or model_value > 0):
        return float(model_value)
    if fill is None:
        raise ScannerError(
            f"{arm_file.path}: joint_limits.{joint}.{key}: expected a number, the model "
            f"{arm_file.model.name} has no such limit"
        )
    return fill


def _read_only(values: list) -> np.ndarray:
    array = np.array(values)
    array.setflags(write=False)
    return array


def add_arm_model(plant: MultibodyPlant, arm_file: ArmFile, text: str, kind: str):
    """Add the arm's model (`text` of `kind` "urdf" or "sdf", from `model_text`) to an
    unfinalised plant, its root link welded at X_WB; its model instance. ScannerError, one line,
    for a model Drake refuses or a flange link the model lacks."""
    parser = Parser(plant)
    for package, folder in arm_file.packages:
        # The arm file's folder wins over Drake's built-in packages (drake_models is remote).
        if parser.package_map().Contains(package):
            parser.package_map().Remove(package)
        parser.package_map().Add(package, str(folder))
    try:
        (instance,) = parser.AddModelsFromString(text, kind)
    except (RuntimeError, ValueError) as e:
        detail = " ".join(str(e).split())
        raise ScannerError(f"{arm_file.path}: model: Drake cannot load it ({detail})") from None
    if not plant.HasBodyNamed(arm_file.flange_link, instance):
        links = ", ".join(plant.get_body(b).name() for b in plant.GetBodyIndices(instance))
        raise ScannerError(
            f"{arm_file.path}: flange_link: expected a link of {arm_file.model.name} "
            f"({links}), got {arm_file.flange_link!r}"
        )
    X_WB = RigidTransform(RollPitchYaw(arm_file.base_rpy_rad), np.array(arm_file.base_xyz_m))
    plant.WeldFrames(plant.world_frame(), _root_body(plant, instance, arm_file).body_frame(), X_WB)
    return instance


def _check_home(arm_file: ArmFile, lower: list[float], upper: list[float]) -> None:
    home = arm_file.home_q_rad
    if home is None:
        return
    if len(home) != len(lower) or not all(
        lo <= q <= hi for q, lo, hi in zip(home, lower, upper, strict=True)
    ):
        raise ScannerError(
            f"{arm_file.path}: home_q_rad: expected {len(lower)} joint positions within the "
            f"joint limits, got {list(home)}"
        )


def load_arm_plant(arm_file: ArmFile, model: tuple[str, str] | None = None) -> ArmPlant:
    """Parse the arm's model (`model`: its text and kind when already read by `model_text`),
    weld its root at X_WB and read the chain. ScannerError, one line, for a model Drake refuses,
    a flange link the model lacks, a limit in neither model nor file."""
    text, kind = model_text(arm_file) if model is None else model
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    instance = add_arm_model(plant, arm_file, text, kind)
    flange_body = plant.GetBodyByName(arm_file.flange_link, instance)
    chain = _chain(plant, instance, flange_body, arm_file)
    redundant = arm_file.ik.redundant_joint
    if redundant is not None and redundant not in [j.name() for j in chain]:
        raise ScannerError(
            f"{arm_file.path}: ik.redundant_joint: expected a joint between the base and the "
            f"flange ({', '.join(j.name() for j in chain)}), got {redundant!r}"
        )
    plant.Finalize()
    diagram = builder.Build()

    limits: dict[str, list[float]] = {"lower": [], "upper": [], "velocity": [], "acceleration": []}
    for joint in chain:
        fill = arm_file.limit_fill(joint.name())
        model_values = {
            "lower": (joint.position_lower_limits()[0], fill.lower_rad, "lower_rad"),
            "upper": (joint.position_upper_limits()[0], fill.upper_rad, "upper_rad"),
            "velocity": (joint.velocity_upper_limits()[0], fill.velocity_rad_s, "velocity_rad_s"),
            "acceleration": (
                joint.acceleration_upper_limits()[0],
                fill.acceleration_rad_s2,
                "acceleration_rad_s2",
            ),
        }
        for key, (value, given, field_name) in model_values.items():
            limits[key].append(_limit(value, given, arm_file, joint.name(), field_name))
    _check_home(arm_file, limits["lower"], limits["upper"])
    return ArmPlant(
        diagram=diagram,
        plant=plant,
        flange_frame=flange_body.body_frame(),
        joint_names=tuple(j.name() for j in chain),
        position_starts=_read_only([j.position_start() for j in chain]),
        lower=_read_only(limits["lower"]),
        upper=_read_only(limits["upper"]),
        velocity=_read_only(limits["velocity"]),
        acceleration=_read_only(limits["acceleration"]),
        revolute=_read_only([j.type_name() == "revolute" for j in chain]),
    )

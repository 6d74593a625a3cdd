"""The work cell as data (WorkcellConfig) and its Drake model (MultibodyPlant + SceneGraph).

World frame W = robot base frame (base mounting face, +z up). The arm (robots/arms) stands on a
table whose top is the plane z = 0; a safety fence stands behind the robot and a radiator beside
it (SDU report, section 4.1); the object hangs from a thin rod above and in front of the robot
because the SDU cell's arm has a short reach.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    Box,
    CollisionFilterDeclaration,
    Convex,
    Cylinder,
    GeometryInstance,
    GeometrySet,
    IllustrationProperties,
    MakeRenderEngineVtk,
    Mesh,
    PerceptionProperties,
    RenderEngineVtkParams,
    RenderLabel,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, SpatialInertia
from pydrake.planning import RobotDiagram, RobotDiagramBuilder

from reconstruction.common.errors import ScannerError
from robots.arms.arm import Arm
from robots.arms.default import DEFAULT_ARM
from robots.models import camera_tool
from robots.models.objects import collision_hull_path

RENDERER_NAME = "vtk"
OBJECT_BODY = "object"


@dataclass(frozen=True)
class CellBox:
    """A static box in the cell: centre p_WB (m), full size (m), colour."""

    name: str
    p_WB: tuple[float, float, float]
    size: tuple[float, float, float]
    rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.6, 1.0)

    def __post_init__(self) -> None:
        if len(self.size) != 3 or not all(math.isfinite(v) and v > 0 for v in self.size):
            raise ScannerError(
                f"boxes.size: expected three positive sizes in metres, got {list(self.size)}"
            )
        if len(self.p_WB) != 3 or not all(math.isfinite(v) for v in self.p_WB):
            raise ScannerError(f"boxes.p_WB: expected three finite numbers, got {list(self.p_WB)}")


DEFAULT_CELL_BOXES: tuple[CellBox, ...] = (
    CellBox("table", (0.15, 0.0, -0.025), (1.3, 1.1, 0.05), (0.45, 0.35, 0.25, 1.0)),
    CellBox("fence", (-0.75, 0.0, 0.85), (0.02, 1.8, 1.8), (0.85, 0.8, 0.1, 1.0)),
    CellBox("radiator", (0.25, -0.75, 0.35), (0.7, 0.1, 0.6), (0.9, 0.9, 0.9, 1.0)),
)


# The rod, the camera's depth window and the arm's reach are sized for objects of a few
# centimetres to half a metre; beyond a metre the size is a unit typed wrongly.
MAX_OBJECT_SIZE_M = 1.0


@dataclass(frozen=True)
class WorkcellConfig:
    """Where things are. Positions in the world (robot base) frame, metres."""

    # Measured: of the centres tried, here the most of a 0.5 m viewing sphere is reachable
    # collision-free (12 %, a cap below the object, elevations -82..-13 deg). None: laid out
    # from the arm's reach before the cell is built (planners/reach.py; a scan of an arm file
    # whose configuration names no centre).
    object_center_m: tuple[float, float, float] | None = (0.40, 0.0, 1.00)
    # Where a table's or turntable's top (the centre of its upper face) stands: the object on
    # it is seen from above and around, not from below as where it hangs. Measured with
    # planners/reach.py's `sphere_share` (96 directions of elevation -10..85 deg, 12 rolls, the
    # carrier in the planner's view): centres 0.6-0.8 m in front of the base and 0.13-0.25 m
    # up reach 8-18 % of that band; at (0.70, 0, 0.15) for a 0.2 m object the views reach
    # elevations 7-63 deg on the side facing the robot (13 % of the band). Nearer, the
    # cameras on that side stand in the arm's own column; farther or higher, the views from
    # above are out of its reach (0.67 m from the shoulder). None: the object centre as
    # configured (or laid out from the arm's reach), as for a hanging.
    support_top_m: tuple[float, float, float] | None = (0.70, 0.0, 0.05)
    object_size_m: float = 0.2
    object_yaw_rad: float = 0.0
    rod_radius_m: float = 0.004
    rod_top_z_m: float = 1.8
    boxes: tuple[CellBox, ...] = field(default=DEFAULT_CELL_BOXES)

    def __post_init__(self) -> None:
        c = self.object_center_m
        if c is not None and (len(c) != 3 or not all(math.isfinite(v) for v in c)):
            raise ScannerError(f"object_center_m: expected three finite numbers, got {c}")
        t = self.support_top_m
        if t is not None and (len(t) != 3 or not all(math.isfinite(v) for v in t) or t[2] <= 0):
            raise ScannerError(
                f"support_top_m: expected three finite numbers, the height above the table "
                f"top (z = 0) positive, got {t}"
            )
        if not (math.isfinite(self.object_size_m) and 0 < self.object_size_m <= MAX_OBJECT_SIZE_M):
            raise ScannerError(
                f"object_size_m: expected a size in metres in (0, 1], got {self.object_size_m}"
            )
        if not (math.isfinite(self.rod_radius_m) and self.rod_radius_m > 0):
            raise ScannerError(
                f"rod_radius_m: expected a positive radius in metres, got {self.rod_radius_m}"
            )
        if not math.isfinite(self.object_yaw_rad):
            raise ScannerError(
                f"object_yaw_rad: expected a finite angle, got {self.object_yaw_rad}"
            )
        if c is not None and not self.rod_top_z_m > c[2]:
            raise ScannerError(
                f"rod_top_z_m: expected above the object centre ({c[2]} m), got {self.rod_top_z_m}"
            )

    def presented_center_m(self, presentation: str) -> tuple[float, float, float] | None:
        """Where the object's centre is when `presentation` holds it: hanging from the rod at
        `object_center_m`; on a table or turntable, half its size above the support's top."""
        if presentation == "hanging" or self.support_top_m is None:
            return self.object_center_m
        x, y, z = self.support_top_m
        return (x, y, z + self.object_size_m / 2)

    @property
    def X_WO(self) -> np.ndarray:
        """Pose of the object frame O in the world."""
        if self.object_center_m is None:
            raise ValueError("the cell's object centre is not laid out yet (scanner.scan.layout)")
        X = np.eye(4)
        cz, sz = math.cos(self.object_yaw_rad), math.sin(self.object_yaw_rad)
        X[:3, :3] = [[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]
        X[:3, 3] = self.object_center_m
        return X


@dataclass
class Workcell:
    """A built cell: the RobotDiagram and the handles every consumer needs."""

    diagram: RobotDiagram
    robot: object  # ModelInstanceIndex of the arm
    config: WorkcellConfig
    has_renderer: bool
    has_object: bool = True
    presentation: str = "hanging"  # what holds the object: the rod, or the turntable
    # The arm's flange frame F in `robot` (where X_FC is measured from).
    flange_frame: str = "tool0"

    @property
    def plant(self) -> MultibodyPlant:
        return self.diagram.plant()

    @property
    def scene_graph(self):
        return self.diagram.scene_graph()

    def object_label(self) -> int:
        """Render label of the object (Drake labels perception geometry by body index)."""
        return int(self.plant.GetBodyByName(OBJECT_BODY).index())


def add_camera_frames(
    plant: MultibodyPlant, arm: Arm, instance, X_FC: np.ndarray, X_CR: np.ndarray
) -> None:
    """Left (C) and right (R) optical frames fixed to the flange at the given hand-eye pose."""
    flange = plant.GetFrameByName(arm.flange_frame, instance)
    left = plant.AddFrame(FixedOffsetFrame("camera_left", flange, RigidTransform(X_FC)))
    plant.AddFrame(FixedOffsetFrame("camera_right", left, RigidTransform(X_CR)))


def _add_tool_geometry(plant: MultibodyPlant, arm: Arm, instance) -> None:
    body = plant.GetFrameByName(arm.flange_frame, instance).body()
    X_BF = plant.GetFrameByName(arm.flange_frame, instance).GetFixedPoseInBodyFrame()
    for i, box in enumerate(camera_tool.tool_visual_boxes()):
        plant.RegisterVisualGeometry(
            body,
            X_BF @ RigidTransform(box.p_FB),
            Box(*box.size),
            f"camera_tool_visual_{i}",
            np.array([0.15, 0.15, 0.18, 1.0]),
        )
    c = camera_tool.tool_collision_box()
    plant.RegisterCollisionGeometry(
        body,
        X_BF @ RigidTransform(c.p_FB),
        Box(*c.size),
        "camera_tool_collision",
        _friction(),
    )


def _filter_tool(plant: MultibodyPlant, scene_graph, arm: Arm, instance) -> None:
    """Exclude the arm's `tool_filtered_links` vs the camera tool from collision checks (why:
    robots.arms.arm.Arm)."""
    tool = plant.GetFrameByName(arm.flange_frame, instance).body()
    for link in arm.tool_filtered_links:
        body = plant.GetBodyByName(link, instance)
        pair = GeometrySet(
            plant.GetCollisionGeometriesForBody(body) + plant.GetCollisionGeometriesForBody(tool)
        )
        filters = CollisionFilterDeclaration().ExcludeWithin(pair)
        scene_graph.collision_filter_manager().Apply(filters)


def _friction():
    from pydrake.multibody.plant import CoulombFriction

    return CoulombFriction(0.5, 0.5)


def _add_cell(plant: MultibodyPlant, config: WorkcellConfig) -> None:
    world = plant.world_body()
    for box in config.boxes:
        X = RigidTransform(np.array(box.p_WB))
        plant.RegisterVisualGeometry(world, X, Box(*box.size), box.name, np.array(box.rgba))
        plant.RegisterCollisionGeometry(world, X, Box(*box.size), box.name, _friction())


@dataclass(frozen=True)
class PlacedObject:
    """The object's textured OBJ (in its frame O) and the point p_OA where its rod is attached."""

    obj_path: Path
    p_OA: tuple[float, float, float]


def placed_object(
    obj_path: Path,
    vertices_O: np.ndarray,
    triangles: np.ndarray,
    R_WO: np.ndarray | None = None,
) -> PlacedObject:
    """The rod hangs straight down the vertical through the object's centre and is attached
    where that line first meets the surface, so the software knows where the rod is (the
    vertical above the scan centre) without knowing the object. An object the line misses
    hangs from its vertex nearest to that line among the top 1 % of heights. `R_WO`: the
    object's orientation in the cell (a re-hung object hangs from its new top)."""
    import open3d as o3d

    R_WO = np.eye(3) if R_WO is None else np.asarray(R_WO, float)
    up_O = R_WO.T @ np.array([0.0, 0.0, 1.0])
    heights = vertices_O @ up_O
    top = float(heights.max())
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(vertices_O.astype(np.float32), triangles.astype(np.uint32))
    start = (top + 1.0) * up_O
    ray = np.array([[*start, *(-up_O)]], np.float32)
    hit = float(scene.cast_rays(o3d.core.Tensor(ray))["t_hit"].numpy()[0])
    if np.isfinite(hit):
        return PlacedObject(Path(obj_path), tuple(float(v) for v in start - hit * up_O))
    high = vertices_O[heights >= top - 0.01 * float(np.ptp(heights))]
    off_axis = high - np.outer(high @ up_O, up_O)
    p = high[int(np.argmin(np.linalg.norm(off_axis, axis=1)))]
    return PlacedObject(Path(obj_path), tuple(float(v) for v in p))


def textured_instance(mesh: Mesh, name: str, label: int) -> GeometryInstance:
    """A visual geometry that keeps its OBJ material (no diffuse override) and a render label."""
    instance = GeometryInstance(RigidTransform(), mesh, name)
    instance.set_illustration_properties(IllustrationProperties())
    perception = PerceptionProperties()
    perception.AddProperty("label", "id", RenderLabel(label))
    instance.set_perception_properties(perception)
    return instance


def keep_out_radius_m(config: WorkcellConfig) -> float:
    """Radius of the sphere that surely holds an object whose largest extent is object_size_m."""
    return config.object_size_m * math.sqrt(3) / 2


# What each presentation puts into the cell to hold the object (robots/models/turntable.py,
# robots/models/table.py).
CELL_PRESENTATIONS = ("hanging", "turntable", "table")


def check_presentation(presentation: str) -> None:
    """Refuse a presentation the cell has no model for (the error names the ones it has)."""
    if presentation not in CELL_PRESENTATIONS:
        raise ScannerError(
            f"presentation: the cell has no model for {presentation!r}; it has "
            f"{', '.join(CELL_PRESENTATIONS)}"
        )


def _add_object(
    plant: MultibodyPlant,
    config: WorkcellConfig,
    obj: PlacedObject | None,
    X_WO: np.ndarray,
    presentation: str = "hanging",
) -> None:
    """The object (a welded body, so it has its own render label) and the rod it hangs from
    (on a turntable: the disc and post it stands on; on the table: its top and leg).

    Without a mesh (the planner's view: the object is unknown) the object is a collision-only
    keep-out sphere around the scan centre and the rod hangs down to the sphere's top.
    """
    instance = plant.AddModelInstance("object")
    body = plant.AddRigidBody(OBJECT_BODY, instance, SpatialInertia.SolidSphereWithMass(0.5, 0.05))
    X_WO = RigidTransform(X_WO)
    plant.WeldFrames(plant.world_frame(), body.body_frame(), X_WO)
    p_OA = np.zeros(3)
    if obj is not None:
        p_OA = np.array(obj.p_OA)
        mesh = Mesh(str(obj.obj_path))
        plant.RegisterVisualGeometry(
            body, textured_instance(mesh, "object_visual", int(body.index()))
        )
        # Collision queries see a mesh as its convex hull: the hull itself, when it was
        # written beside the OBJ, spares Drake parsing and hulling the whole mesh again.
        hull = collision_hull_path(obj.obj_path)
        collision = Convex(str(hull)) if hull.is_file() else mesh
        plant.RegisterCollisionGeometry(
            body, RigidTransform(), collision, "object_collision", _friction()
        )
    else:
        radius = keep_out_radius_m(config)
        p_OA = np.array([0.0, 0.0, radius])
        plant.RegisterCollisionGeometry(
            body, RigidTransform(), Sphere(radius), "object_keep_out", _friction()
        )
    if presentation == "turntable":
        from robots.models.turntable import add_turntable

        add_turntable(plant, config)
        return
    if presentation == "table":
        from robots.models.table import add_table

        add_table(plant, config)
        return
    p_WA = X_WO @ p_OA
    length = config.rod_top_z_m - p_WA[2]
    # The rod is vertical in W; O may be yawed, so express the rod's pose through W.
    X_WR = RigidTransform(np.array([p_WA[0], p_WA[1], p_WA[2] + length / 2]))
    X_OR = X_WO.inverse() @ X_WR
    rod = Cylinder(config.rod_radius_m, length)
    plant.RegisterVisualGeometry(body, X_OR, rod, "rod", np.array([0.7, 0.7, 0.72, 1.0]))
    plant.RegisterCollisionGeometry(body, X_OR, rod, "rod", _friction())


def build_workcell(
    config: WorkcellConfig,
    obj: PlacedObject | None,
    X_FC: np.ndarray,
    X_CR: np.ndarray,
    arm: Arm = DEFAULT_ARM,
    renderer: bool = False,
    meshcat=None,
    extras: Sequence[Callable[[MultibodyPlant, object], None]] = (),
    include_object: bool = True,
    X_WO: np.ndarray | None = None,
    meshcat_prefix: str = "visualizer",
    presentation: str = "hanging",
) -> Workcell:
    """Robot, camera tool (frames at the given X_FC), cell boxes and object in one RobotDiagram.

    `obj` is the true textured object (simulator); None gives the planner's view, a keep-out
    sphere of the configured object size around the scan centre. `meshcat` (a pydrake Meshcat)
    adds a live visualiser, published by `ForcedPublish` on the diagram. `extras` add more
    things before the plant is finalised, each called as extra(plant, robot_instance) (e.g. a
    calibration board, a marker on the flange); `include_object=False` leaves the object, its
    keep-out sphere and its rod out of the cell (calibration needs a clear view of the board).
    `X_WO`: the object's pose (default the configuration's; a re-hung object differs).
    `meshcat_prefix`: where in meshcat's scene tree the geometry goes (Drake's default puts it
    under /drake/visualizer; a path starting with / is absolute). `presentation`: what holds
    the object, "hanging" (the rod), "turntable" (robots/models/turntable.py) or "table"
    (robots/models/table.py).
    """
    check_presentation(presentation)
    builder = RobotDiagramBuilder(time_step=0.0)
    plant = builder.plant()
    if renderer:
        builder.scene_graph().AddRenderer(
            RENDERER_NAME, MakeRenderEngineVtk(RenderEngineVtkParams())
        )
    instance = arm.add_model(plant)
    _add_tool_geometry(plant, arm, instance)
    add_camera_frames(plant, arm, instance, X_FC, X_CR)
    _add_cell(plant, config)
    if include_object:
        _add_object(plant, config, obj, config.X_WO if X_WO is None else X_WO, presentation)
    for extra in extras:
        extra(plant, instance)
    plant.Finalize()
    _filter_tool(plant, builder.scene_graph(), arm, instance)
    if meshcat is not None:
        from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams

        MeshcatVisualizer.AddToBuilder(
            builder.builder(),
            builder.scene_graph(),
            meshcat,
            MeshcatVisualizerParams(prefix=meshcat_prefix),
        )
    return Workcell(
        builder.Build(),
        instance,
        config,
        renderer,
        include_object,
        presentation,
        arm.flange_frame,
    )

"""The Drake scene the cell video renders: the scan's cell, object and truth plus the intruders'
forearms, posed at a time and joints, and views of it that show only some of its geometry (the
robot, the camera tool, the object, the static background)."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from pydrake.geometry import Cylinder, Role
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import SpatialInertia

from reconstruction.common.transforms import invert, transform_points
from robots.arms.arm import Arm
from robots.models.objects import ObjectMesh
from robots.models.workcell import WorkcellConfig, build_workcell, placed_object
from robots.simulation.cell import textured_object
from robots.simulation.cell_video.intruders import IntruderPath
from robots.simulation.cell_video.roi import (
    MAX_ROI_FRACTION,
    bounding_radius_m,
    roi_camera,
    spheres_roi_px,
)
from robots.simulation.stereo_camera import _RenderedCamera
from robots.simulation.truth import Truth

# A blue work-jacket sleeve: mid grey to a grey camera (0.42 lit head-on), apart from the pale
# walls and radiator (0.8-0.9) and the dark table top. Bare skin was the grey of the wall behind
# and left most of the forearm invisible to a grey camera.
FOREARM_RGBA = (0.2, 0.4, 0.8, 1.0)
# Where an absent intruder waits: far beyond the renderer's far clip (5 m), so never drawn.
PARKED_p_W = (0.0, 0.0, -100.0)


class _Intruders:
    """A build_workcell extra: one free body per path, a visual-only cylinder each."""

    def __init__(self, paths: Sequence[IntruderPath]) -> None:
        self.paths = tuple(paths)
        self.bodies: list = []

    def __call__(self, plant: MultibodyPlant, robot_instance) -> None:
        for i, path in enumerate(self.paths):
            instance = plant.AddModelInstance(f"intruder_{i}")
            inertia = SpatialInertia.SolidCylinderWithMass(
                1.5, path.radius_m, path.length_m, [0.0, 0.0, 1.0]
            )
            body = plant.AddRigidBody(f"intruder_{i}", instance, inertia)
            plant.RegisterVisualGeometry(
                body,
                RigidTransform(),
                Cylinder(path.radius_m, path.length_m),
                f"intruder_{i}_visual",
                np.array(FOREARM_RGBA),
            )
            self.bodies.append(body)


def _is_tool_geometry(cell, gid) -> bool:
    """The camera tool's visual boxes (robots/models/workcell.py names them
    camera_tool_visual_i)."""
    return "camera_tool_visual" in cell.scene_graph.model_inspector().GetName(gid)


class VideoScene:
    """One diagram built for the video: the scan's cell config, object mesh, truth and robot
    (the scan's Simulation is not touched) plus a free cylinder per intruder path, rendered by
    Drake's VTK renderer, so a forearm occludes and is occluded like any other geometry.

    `context` is the whole scene. `robot_view` (links and camera tool), `tool_view` (the camera
    tool alone) and `object_view` (the hung object and its rod) are contexts that show only
    those, with the perception labels `robot_labels` (also the tool's), `object_labels` and
    `intruder_labels`; `tool_spheres` are (geometry id, bounding radius (m)) of the tool's
    boxes. Renders are in W (robot base frame); cameras are posed by X_WS.
    """

    def __init__(
        self,
        cell: WorkcellConfig,
        object_mesh: ObjectMesh | None,
        truth: Truth,
        arm: Arm,
        paths: tuple[IntruderPath, ...],
        roi_rendering: bool,
    ) -> None:
        self.paths = paths
        self._intruders = _Intruders(self.paths)
        obj = None
        if object_mesh is not None:
            obj = placed_object(
                textured_object(object_mesh, truth.seed),
                object_mesh.vertices,
                object_mesh.triangles,
                truth.X_WO[:3, :3],
            )
        self.cell = build_workcell(
            cell,
            obj,
            truth.X_FC,
            truth.stereo.X_CR,
            arm,
            renderer=True,
            extras=(self._intruders,),
            include_object=object_mesh is not None,
            X_WO=truth.X_WO,
        )
        self.context = self.cell.diagram.CreateDefaultContext()
        plant = self.cell.plant
        robot_bodies = {int(b) for b in plant.GetBodyIndices(self.cell.robot)}
        object_bodies = (
            {int(plant.GetBodyByName("object").index())} if self.cell.has_object else set()
        )
        self.robot_view, self.robot_labels = self._only(robot_bodies)
        inspector = self.cell.scene_graph.model_inspector()
        tool = [gid for gid, _ in self._geometries() if _is_tool_geometry(self.cell, gid)]
        self.tool_view = self._only_geometries(set(tool))
        self.tool_spheres = [(gid, bounding_radius_m(inspector.GetShape(gid))) for gid in tool]
        self.object_view, self.object_labels = self._only(object_bodies)
        intruder_bodies = {int(b.index()) for b in self._intruders.bodies}
        self.intruder_labels = self._labels_of(intruder_bodies)
        # Only the arm and the forearms move: a frame renders the window holding them over a
        # background rendered once without them (half the time of two whole renders).
        moving = robot_bodies | intruder_bodies
        static = {body for _, body in self._geometries()} - moving
        self._background_view, _ = self._only(static)
        self._backgrounds: dict[int, np.ndarray] = {}
        inspector = self.cell.scene_graph.model_inspector()
        self._moving = [
            (gid, body, bounding_radius_m(inspector.GetShape(gid)))
            for gid, body in self._geometries()
            if body in moving
        ]
        self._roi_rendering = roi_rendering and all(r is not None for *_, r in self._moving)
        self._intruder_body_path = {
            int(b.index()): path for b, path in zip(self._intruders.bodies, self.paths, strict=True)
        }

    # --- views ----------------------------------------------------------------------------
    def _geometries(self) -> list[tuple[object, int]]:
        """(geometry id, body index) of every geometry with a perception role."""
        plant, inspector = self.cell.plant, self.cell.scene_graph.model_inspector()
        out = []
        for gid in inspector.GetAllGeometryIds(Role.kPerception):
            body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
            out.append((gid, -1 if body is None else int(body.index())))
        return out

    def _labels_of(self, bodies: set[int]) -> np.ndarray:
        inspector = self.cell.scene_graph.model_inspector()
        labels = {
            int(inspector.GetPerceptionProperties(gid).GetProperty("label", "id"))
            for gid, body in self._geometries()
            if body in bodies
        }
        return np.array(sorted(labels), np.int32)

    def _only(self, bodies: set[int]):
        """A context in which only the geometries of `bodies` are seen, and their labels."""
        keep = {gid for gid, body in self._geometries() if body in bodies}
        return self._only_geometries(keep), self._labels_of(bodies)

    def _only_geometries(self, keep: set):
        """A context in which only the geometries with ids in `keep` are seen."""
        context = self.cell.diagram.CreateDefaultContext()
        sg = self.cell.scene_graph
        sg_context = sg.GetMyMutableContextFromRoot(context)
        source = self.cell.plant.get_source_id()
        for gid, _ in self._geometries():
            if gid not in keep:
                sg.RemoveRole(sg_context, source, gid, Role.kPerception)
        return context

    # --- rendering ------------------------------------------------------------------------
    def pose(self, context, q_true: np.ndarray, t_s: float | None) -> None:
        """Puts the arm at joints q_true (rad) and each intruder where its path has it at t_s
        (parked out of sight when absent or t_s is None)."""
        plant = self.cell.plant
        plant_context = plant.GetMyContextFromRoot(context)
        plant.SetPositions(plant_context, self.cell.robot, q_true)
        for path, body in zip(self.paths, self._intruders.bodies, strict=True):
            X = None if t_s is None else path.X_WI(t_s)
            pose = RigidTransform(np.array(PARKED_p_W)) if X is None else RigidTransform(X)
            plant.SetFreeBodyPose(plant_context, body, pose)

    def query(self, context):
        sg = self.cell.scene_graph
        return sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(context))

    def _render_grey(self, context, camera, X_WS: np.ndarray) -> np.ndarray:
        sg = self.cell.scene_graph
        image = self.query(context).RenderColorImage(
            camera, sg.world_frame_id(), RigidTransform(X_WS)
        )
        return cv2.cvtColor(np.asarray(image.data), cv2.COLOR_RGBA2GRAY)

    def _roi(self, camera: _RenderedCamera, X_WS: np.ndarray, t_s: float):
        """The render-grid window holding the moving geometry seen from X_WS, or None."""
        query = self.query(self.context)
        X_SW = invert(X_WS)
        centres, radii = [], []
        for gid, body, radius in self._moving:
            path = self._intruder_body_path.get(body)
            if path is not None and path.position_W(t_s) is None:
                continue
            centres.append(query.GetPoseInWorld(gid).translation())
            radii.append(radius)
        p_S = transform_points(X_SW, np.array(centres).reshape(-1, 3))
        K, size = camera.maps.K_render, camera.maps.render_size
        roi = spheres_roi_px(p_S, np.array(radii), K, size, margin_px=2)
        if roi is None or (roi[2] - roi[0]) * (roi[3] - roi[1]) > MAX_ROI_FRACTION * np.prod(size):
            return None
        return roi

    def grey(self, camera: _RenderedCamera, X_WS: np.ndarray, t_s: float) -> np.ndarray:
        """The grey image of the posed scene (`context`) on the sensor grid (distorted,
        noise-free). With `roi_rendering` only the window holding the arm and the forearms is
        rendered, over a background rendered once per camera: about 13 ms per camera for the
        default view against 28 ms for a whole render (640x480, software OpenGL), and ~10 edge
        pixels differ from a whole render."""
        roi = self._roi(camera, X_WS, t_s) if self._roi_rendering else None
        if roi is None:
            return camera.distort(self._render_grey(self.context, camera.color, X_WS))
        key = id(camera)
        if key not in self._backgrounds:
            self._backgrounds[key] = self._render_grey(self._background_view, camera.color, X_WS)
        grey = self._backgrounds[key].copy()
        u0, v0, u1, v1 = roi
        K = camera.maps.K_render
        grey[v0:v1, u0:u1] = self._render_grey(self.context, roi_camera(K, roi), X_WS)
        return camera.distort(grey)

    def labels(self, context, camera: _RenderedCamera, X_WS: np.ndarray) -> np.ndarray:
        """The perception labels (int32) of a posed context on the sensor grid (distorted)."""
        sg = self.cell.scene_graph
        image = self.query(context).RenderLabelImage(
            camera.color, sg.world_frame_id(), RigidTransform(X_WS)
        )
        return camera.distort(np.asarray(image.data)[..., 0].astype(np.int32), nearest=True)

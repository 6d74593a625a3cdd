"""A blinking marker on the flange (the KTH report's LED), for eye-to-hand calibration.

A small sphere fixed to the flange at p_FM that emits light: a glTF mesh with an unlit white
material (KHR_materials_unlit, which Drake's VTK renderer honours), so it renders uniformly
white whatever the lighting. A lit (Phong) sphere would not do: Drake's default light is
directional along each camera's optical axis, so a sphere off that axis is brighter on one side
and its centroid moved by 0.3-0.6 px (2 mm of triangulated depth at 1 m). The LED is switched
off by removing the sphere's perception role in a context (the camera then sees whatever is
behind it), and on again by restoring it.
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.geometry import Mesh, Role, RoleAssign
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant

from reconstruction.common.errors import ScannerError
from robots.models.workcell import textured_instance


def write_emissive_sphere_gltf(path: Path, radius_m: float, rings: int = 24) -> Path:
    """A UV sphere as a self-contained glTF (embedded buffer) with an unlit white material."""
    theta = np.linspace(0, np.pi, rings + 1)
    phi = np.linspace(0, 2 * np.pi, 2 * rings + 1)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    normals = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], -1)
    normals = normals.reshape(-1, 3).astype(np.float32)
    vertices = (radius_m * normals).astype(np.float32)
    cols = 2 * rings + 1
    quads = [
        (i * cols + j, (i + 1) * cols + j, i * cols + j + 1, (i + 1) * cols + j + 1)
        for i in range(rings)
        for j in range(2 * rings)
    ]
    indices = np.array([[a, b, c, c, b, d] for a, b, c, d in quads], np.uint16).ravel()
    blob = vertices.tobytes() + normals.tobytes() + indices.tobytes()
    nv, nn = vertices.nbytes, normals.nbytes
    gltf = {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [
            {
                "primitives": [
                    {"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}
                ]
            }
        ],
        "materials": [
            {
                "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0},
                "extensions": {"KHR_materials_unlit": {}},
            }
        ],
        "buffers": [
            {
                "byteLength": len(blob),
                "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode(),
            }
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": nv, "target": 34962},
            {"buffer": 0, "byteOffset": nv, "byteLength": nn, "target": 34962},
            {"buffer": 0, "byteOffset": nv + nn, "byteLength": indices.nbytes, "target": 34963},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": len(vertices),
                "type": "VEC3",
                "min": vertices.min(axis=0).tolist(),
                "max": vertices.max(axis=0).tolist(),
            },
            {"bufferView": 1, "componentType": 5126, "count": len(normals), "type": "VEC3"},
            {"bufferView": 2, "componentType": 5123, "count": len(indices), "type": "SCALAR"},
        ],
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(gltf))
    return path


@dataclass(frozen=True)
class MarkerConfig:
    """Marker centre p_FM (m, flange frame) and radius (m). Default: on the flange axis just in
    front of the camera tool, between the lenses, 5 mm like the KTH report's diode."""

    p_FM: tuple[float, float, float] = (0.0, 0.0, 0.088)
    radius_m: float = 0.008

    def __post_init__(self) -> None:
        if not self.radius_m > 0:
            raise ScannerError(f"marker.radius_m: expected a positive radius, got {self.radius_m}")


class BlinkingMarker:
    """Adds the marker to a plant (call as a build_workcell extra) and switches it in a context."""

    def __init__(self, config: MarkerConfig, directory: Path, flange_frame: str) -> None:
        """`flange_frame`: the frame of the arm's flange the marker is fixed to (the arm's)."""
        self.config = config
        self._flange_frame = flange_frame
        self._gltf = write_emissive_sphere_gltf(
            Path(directory) / f"marker-{config.radius_m:.6f}.gltf", config.radius_m
        )
        self._geometry_id = None
        self._source_id = None
        self._properties = None

    def __call__(self, plant: MultibodyPlant, robot_instance) -> None:
        flange = plant.GetFrameByName(self._flange_frame, robot_instance)
        X_BM = flange.GetFixedPoseInBodyFrame() @ RigidTransform(np.array(self.config.p_FM))
        label = int(flange.body().index())
        instance = textured_instance(Mesh(str(self._gltf)), "blinking_marker", label)
        instance.set_pose(X_BM)
        self._geometry_id = plant.RegisterVisualGeometry(flange.body(), instance)
        self._source_id = plant.get_source_id()

    def set_lit(self, scene_graph, scene_graph_context, lit: bool) -> None:
        if self._geometry_id is None:
            raise RuntimeError("the marker was never added to a plant")
        inspector = scene_graph.model_inspector()
        if self._properties is None:
            self._properties = inspector.GetPerceptionProperties(self._geometry_id)
        state = scene_graph_context
        has = (
            scene_graph.get_query_output_port()
            .Eval(state)
            .inspector()
            .GetPerceptionProperties(self._geometry_id)
            is not None
        )
        if lit and not has:
            scene_graph.AssignRole(
                state, self._source_id, self._geometry_id, self._properties, RoleAssign.kNew
            )
        elif not lit and has:
            scene_graph.RemoveRole(state, self._source_id, self._geometry_id, Role.kPerception)

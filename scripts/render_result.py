"""Render result meshes headless (Drake VTK) to a PNG, e.g. for the README.

    python scripts/render_result.py SCAN_DIR/results/mesh_poisson.ply SCAN_DIR/truth_mesh.ply \
        --out docs/result.png
Each mesh is rendered from the same two viewpoints (from below and from the side); images are
tiled one row per mesh.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
from pydrake.geometry import (
    ClippingRange,
    ColorRenderCamera,
    GeometryInstance,
    IllustrationProperties,
    MakeRenderEngineVtk,
    Mesh,
    PerceptionProperties,
    RenderCameraCore,
    RenderEngineVtkParams,
    Rgba,
    SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo

from planners.ik import look_at_rotation


def render(mesh_path: Path, size: int, directions: list[np.ndarray]) -> list[np.ndarray]:
    mesh = o3d.io.read_triangle_mesh(str(mesh_path))
    mesh.compute_vertex_normals()
    centre = mesh.get_axis_aligned_bounding_box().get_center()
    extent = float(np.max(mesh.get_axis_aligned_bounding_box().get_extent()))
    with tempfile.TemporaryDirectory() as tmp:
        obj = Path(tmp) / "mesh.obj"
        o3d.io.write_triangle_mesh(
            str(obj), mesh, write_vertex_normals=True, write_vertex_colors=False
        )
        builder = DiagramBuilder()
        sg = builder.AddSystem(SceneGraph())
        sg.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
        source = sg.RegisterSource("result")
        instance = GeometryInstance(RigidTransform(), Mesh(str(obj)), "mesh")
        instance.set_illustration_properties(IllustrationProperties())
        perception = PerceptionProperties()
        perception.AddProperty("phong", "diffuse", Rgba(0.8, 0.75, 0.65, 1.0))
        instance.set_perception_properties(perception)
        sg.RegisterAnchoredGeometry(source, instance)
        diagram = builder.Build()
        context = diagram.CreateDefaultContext()
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(context))
        f = size * 1.2
        core = RenderCameraCore(
            "vtk",
            CameraInfo(size, size, f, f, size / 2, size / 2),
            ClippingRange(0.01, 10.0),
            RigidTransform(),
        )
        images = []
        for d in directions:
            p = centre + 1.3 * extent * d / np.linalg.norm(d)
            X_WV = RigidTransform(RotationMatrix(look_at_rotation(p, centre)), p)
            image = query.RenderColorImage(
                ColorRenderCamera(core, False), sg.world_frame_id(), X_WV
            )
            images.append(np.array(image.data)[..., :3])
    return images


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("meshes", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--size", type=int, default=360)
    args = parser.parse_args()
    directions = [np.array([-0.6, -0.8, -0.9]), np.array([-1.0, 0.3, 0.1])]
    rows = [np.hstack(render(m, args.size, directions)) for m in args.meshes]
    cv2.imwrite(str(args.out), cv2.cvtColor(np.vstack(rows), cv2.COLOR_RGB2BGR))
    print(args.out)


if __name__ == "__main__":
    main()

"""Headless pictures of a triangle mesh with Drake's VTK renderer (no display needed).

A mesh can carry one scalar per vertex drawn through a colour map: the map becomes a one-row
texture and each vertex's texture coordinate is its place on it, so colours blend along the
map (not through RGB) across a triangle, and one value always gets the same colour.

Or it carries its own colours (from the images it was built from): the renderer reads no
vertex colours from a mesh file, so each triangle gets a texel of its own in a square texture,
holding the mean of its vertices' colours, and all three of its corners point at that texel's
centre (a flat colour per triangle; a model's triangles are smaller than its pixels).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

# Where the cameras are, seen from the mesh's centre: below at the side, as the robot sees a
# hung object, and at the side.
DEFAULT_DIRECTIONS = (np.array([-0.6, -0.8, -0.9]), np.array([-1.0, 0.3, 0.1]))
PLAIN_COLOUR = (0.8, 0.75, 0.65)


def _rows(line_format: str, values: np.ndarray) -> str:
    """Every row of `values` through `line_format` in one C-level formatting call (several
    times faster than numpy.savetxt for the ~10^5-row meshes of a scan)."""
    return (line_format * len(values)) % tuple(values.ravel().tolist())


def _face_texture(triangles: np.ndarray, vertex_rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A square texture with one texel per triangle (its vertices' mean colour) and each
    triangle's texture coordinate, at its texel's centre."""
    t = np.asarray(triangles, np.int64)
    side = max(1, math.ceil(math.sqrt(len(t))))
    rgb = np.asarray(vertex_rgb, float)[t].mean(axis=1)
    texture = np.zeros((side * side, 3), np.uint8)
    texture[: len(t)] = np.clip(np.round(rgb), 0, 255).astype(np.uint8)
    k = np.arange(len(t))
    # OBJ's v runs up from the image's bottom row.
    uv = np.c_[(k % side + 0.5) / side, 1.0 - (k // side + 0.5) / side]
    return texture.reshape(side, side, 3), uv


def _write_obj(folder: Path, vertices, triangles, u: np.ndarray | None, texture) -> Path:
    import cv2
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(vertices, float)),
        o3d.utility.Vector3iVector(np.asarray(triangles, np.int32)),
    )
    mesh.compute_vertex_normals()
    obj = folder / "mesh.obj"
    t = np.asarray(triangles, np.int64) + 1
    parts = ["mtllib mesh.mtl\nusemtl values\n" if u is not None else ""]
    parts.append(_rows("v %.7f %.7f %.7f\n", np.asarray(vertices, float)))
    parts.append(_rows("vn %.5f %.5f %.5f\n", np.asarray(mesh.vertex_normals)))
    if texture is not None and np.ndim(texture) == 3:
        # One texture coordinate per triangle (the face texture).
        parts.append(_rows("vt %.7f %.7f\n", np.asarray(u, float)))
        k = np.arange(1, len(t) + 1)[:, None]
        corners = np.stack([t, np.repeat(k, 3, axis=1), t], axis=2).reshape(len(t), 9)
        parts.append(_rows("f %d/%d/%d %d/%d/%d %d/%d/%d\n", corners))
    elif u is None:
        parts.append(_rows("f %d//%d %d//%d %d//%d\n", np.repeat(t, 2, axis=1)))
    else:
        parts.append(_rows("vt %.6f %.6f\n", np.c_[u, np.full(len(u), 0.5)]))
        parts.append(_rows("f %d/%d/%d %d/%d/%d %d/%d/%d\n", np.repeat(t, 3, axis=1)))
    obj.write_text("".join(parts))
    if texture is not None and np.ndim(texture) == 3:
        cv2.imwrite(str(folder / "map.png"), cv2.cvtColor(texture, cv2.COLOR_RGB2BGR))
        (folder / "mesh.mtl").write_text("newmtl values\nKa 1 1 1\nKd 1 1 1\nmap_Kd map.png\n")
    elif u is not None:
        strip = np.repeat(np.asarray(texture, np.uint8)[None], 4, axis=0)
        cv2.imwrite(str(folder / "map.png"), cv2.cvtColor(strip, cv2.COLOR_RGB2BGR))
        (folder / "mesh.mtl").write_text("newmtl values\nKa 1 1 1\nKd 1 1 1\nmap_Kd map.png\n")
    return obj


def render_mesh(
    vertices: np.ndarray,
    triangles: np.ndarray,
    size_px: int = 480,
    directions: Sequence[np.ndarray] = DEFAULT_DIRECTIONS,
    values01: np.ndarray | None = None,
    colour_map: np.ndarray | None = None,
    vertex_rgb: np.ndarray | None = None,
    up_W=(0.0, 0.0, 1.0),
) -> list[np.ndarray]:
    """One RGB image (size_px square) per camera direction (from the mesh's centre), the
    whole mesh in view.
    `values01`: per vertex, its place in [0, 1] on `colour_map` ((K, 3) uint8 RGB);
    `vertex_rgb`: or per vertex its own colour ((V, 3), 0-255); `up_W`: up in the pictures."""
    from pydrake.geometry import (
        ClippingRange,
        ColorRenderCamera,
        GeometryInstance,
        MakeRenderEngineVtk,
        Mesh,
        PerceptionProperties,
        RenderCameraCore,
        RenderEngineVtkParams,
        Rgba,
        SceneGraph,
    )
    from pydrake.math import RigidTransform, RotationMatrix
    from pydrake.systems.sensors import CameraInfo

    from planners.ik import look_at_rotation

    v = np.asarray(vertices, float)
    # Texture lookups at exactly 0 or 1 blend with the strip's border.
    u = None if values01 is None else np.clip(np.asarray(values01, float), 0.002, 0.998)
    texture = colour_map
    if vertex_rgb is not None:
        texture, u = _face_texture(triangles, vertex_rgb)
    with tempfile.TemporaryDirectory() as tmp:
        obj = _write_obj(Path(tmp), v, triangles, u, texture)
        # A SceneGraph without a diagram: a diagram's Python objects form a reference cycle,
        # which left the renderer (and its GL context) to whatever thread collects garbage next;
        # this one is freed on return, in the thread that rendered.
        sg = SceneGraph()
        sg.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
        source = sg.RegisterSource("mesh_render")
        instance = GeometryInstance(RigidTransform(), Mesh(str(obj)), "mesh")
        perception = PerceptionProperties()
        if u is None:
            perception.AddProperty("phong", "diffuse", Rgba(*PLAIN_COLOUR, 1.0))
        instance.set_perception_properties(perception)
        sg.RegisterAnchoredGeometry(source, instance)
        query = sg.get_query_output_port().Eval(sg.CreateDefaultContext())
        centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
        radius = float(np.linalg.norm(v - centre, axis=1).max())
        focal = 1.2 * size_px
        # Far enough that the bounding sphere fits the narrower half-angle with a margin.
        distance = 1.02 * radius * np.hypot(focal, size_px / 2) / (size_px / 2)
        core = RenderCameraCore(
            "vtk",
            CameraInfo(size_px, size_px, focal, focal, size_px / 2, size_px / 2),
            ClippingRange(max(1e-3, distance - 2 * radius), distance + 2 * radius),
            RigidTransform(),
        )
        images = []
        for d in directions:
            p = centre + distance * np.asarray(d, float) / np.linalg.norm(d)
            X_WV = RigidTransform(RotationMatrix(look_at_rotation(p, centre, up_W=up_W)), p)
            image = query.RenderColorImage(
                ColorRenderCamera(core, False), sg.world_frame_id(), X_WV
            )
            images.append(np.array(image.data)[..., :3].copy())
    return images

"""The fallback for small holes VTK's filler leaves open: a fan over a simple boundary loop."""

import numpy as np
import open3d as o3d

from reconstruction.surfaces.topology import _fan_fill, mesh_quality


def test_a_small_simple_hole_is_closed_watertight():
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=0.01, resolution=12)
    triangles = np.asarray(sphere.triangles)
    vertices = np.asarray(sphere.vertices)
    # Open a hole: drop the fan of triangles around one vertex (its one-ring becomes the loop).
    hole_vertex = int(np.argmax(vertices[:, 0]))
    kept = triangles[~np.any(triangles == hole_vertex, axis=1)]
    opened = o3d.geometry.TriangleMesh(sphere.vertices, o3d.utility.Vector3iVector(kept))
    assert mesh_quality(opened).boundary_edges > 0
    closed = _fan_fill(vertices, kept, max_radius_m=0.01)
    mesh = o3d.geometry.TriangleMesh(sphere.vertices, o3d.utility.Vector3iVector(closed))
    quality = mesh_quality(mesh)
    assert quality.watertight and quality.boundary_edges == 0
    assert len(closed) == len(kept) + (len(triangles) - len(kept)) - 2  # a fan: loop - 2


def test_a_hole_larger_than_the_radius_stays_open():
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=0.01, resolution=12)
    triangles = np.asarray(sphere.triangles)
    hole_vertex = int(np.argmax(np.asarray(sphere.vertices)[:, 0]))
    kept = triangles[~np.any(triangles == hole_vertex, axis=1)]
    closed = _fan_fill(np.asarray(sphere.vertices), kept, max_radius_m=0.0001)
    assert len(closed) == len(kept)

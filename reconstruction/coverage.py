"""How much of the object the data cover, estimated without truth.

An untrimmed Poisson surface of the fused cloud is closed: where no view saw the object it
bridges the gap with a smooth patch of about the missing area. The share of that closed
surface lying within `supported_within_m` of a measured point is the coverage estimate; the
simulator's `observed_fraction` (the true surface any camera saw) is what it estimates.
"""

from __future__ import annotations

import numpy as np

from reconstruction.surfaces import FusedCloud


def coverage_estimate(
    fused: FusedCloud,
    supported_within_m: float = 0.002,
    poisson_depth: int = 7,
    samples: int = 50_000,
) -> float:
    """The fraction (0-1) of the closed surface through the data that the data support."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    if len(fused) < 100:
        return 0.0
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(fused.points_W))
    cloud.normals = o3d.utility.Vector3dVector(fused.normals_W)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        cloud, depth=poisson_depth, n_threads=1
    )
    # Poisson also closes the box around the data far from it; keep the component that
    # holds the data (the largest by triangles).
    clusters, counts, _ = mesh.cluster_connected_triangles()
    mesh.remove_triangles_by_mask(np.asarray(clusters) != int(np.argmax(counts)))
    mesh.remove_unreferenced_vertices()
    o3d.utility.random.seed(0)
    points = np.asarray(mesh.sample_points_uniformly(samples).points)
    distance, _ = cKDTree(fused.points_W).query(points)
    return float(np.mean(distance <= supported_within_m))

"""Surface samples of a placed object as one pass of a scan measures them, with a texture:
the inputs of the hanging-alignment tests."""

from __future__ import annotations

import numpy as np

from reconstruction.common.transforms import transform_points


def partial_cloud(vertices, triangles, X, seed: int, texture=None):
    """Surface samples of the object placed at X, only its lower 70 % (a hung object seen
    from below), with 0.2 mm noise: what one pass of a scan measures. With `texture` (object
    frame points -> grey), also their colours."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.array(vertices, np.float64)),
        o3d.utility.Vector3iVector(np.array(triangles, np.int32)),
    )
    o3d.utility.random.seed(seed)
    p_O = np.asarray(mesh.sample_points_uniformly(60_000).points)
    p = transform_points(X, p_O)
    z = p[:, 2]
    keep = z < z.min() + 0.7 * np.ptp(z)
    points = p[keep] + np.random.default_rng(seed).normal(0, 0.0002, (keep.sum(), 3))
    if texture is None:
        return points
    grey = np.clip(texture(p_O[keep]), 0, 255).astype(np.uint8)
    return points, np.repeat(grey[:, None], 3, axis=1)


def stripes(p_O: np.ndarray) -> np.ndarray:
    return 128 + 100 * np.sin(p_O[:, 0] / 0.006) * np.cos(p_O[:, 1] / 0.009)


def other_stripes(p_O: np.ndarray) -> np.ndarray:
    return 128 + 100 * np.sin(p_O[:, 2] / 0.004 + 1.0)

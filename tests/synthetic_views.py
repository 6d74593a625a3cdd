"""Synthetic scans for the reconstruction tests: a true mesh ray-cast from known camera poses.

No stereo matching here: each view is the visible part of the true surface seen through a pinhole
model, with Gaussian depth noise along the ray, which is what the stereo module hands over (its
measured noise in the prototype: 0.17 mm median, 0.7 mm p90). The robot is replaced by flange
poses X_WF = X_WC_true @ inv(X_FC_true), optionally with small per-view errors standing in for
the joint offsets, and the software gets a nominal X_FC that is 3 mm / 1 deg off the truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from reconstruction.common.sphere import fibonacci_directions
from reconstruction.common.transforms import (
    invert,
    make_pose,
    rotation_about,
    transform_points,
    twist_to_pose,
)
from reconstruction.registration.views import DepthImage, ViewCloud
from robots.models.camera_tool import nominal_X_FC
from robots.models.objects import resolve_object

OBJECT_CENTER_W = np.array([0.30, 0.0, 0.78])  # the default cell's scan centre
# The view direction the RX60 reaches best: from the robot's side, slightly from below
# (scanner.scan.preview.first_reachable_view).
ROBOT_SIDE = np.array([-1.0, 0.0, -0.3]) / np.linalg.norm([-1.0, 0.0, -0.3])


@dataclass(frozen=True, eq=False)
class SyntheticScan:
    views: list[ViewCloud]
    X_FC_true: np.ndarray
    X_FC_nominal: np.ndarray
    X_WC_true: list[np.ndarray]
    vertices_W: np.ndarray
    triangles: np.ndarray


def look_at(p_WC: np.ndarray, p_WT: np.ndarray, roll_rad: float) -> np.ndarray:
    """X_WC with +z_C towards the target, +y_C as close to -z_W as possible, then rolled."""
    z = p_WT - p_WC
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    x = np.cross(-up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1) @ rotation_about(np.array([0, 0, 1.0]), roll_rad)
    return make_pose(R, p_WC)


def cap_directions(n: int, axis: np.ndarray, half_angle_rad: float) -> np.ndarray:
    """n directions spread over a spherical cap (Fibonacci spiral in the cap's area)."""
    local = fibonacci_directions(n, math.cos(half_angle_rad), 1.0)
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return local @ np.stack([e1, e2, a])


def sphere_directions(n: int) -> np.ndarray:
    return cap_directions(n, np.array([0, 0, 1.0]), math.pi)


def render_depth(
    scene: o3d.t.geometry.RaycastingScene, X_WC: np.ndarray, K: np.ndarray, size: tuple[int, int]
) -> np.ndarray:
    """Exact depth (H, W) along +z_C of the first hit, 0 where the ray misses."""
    w, h = size
    u, v = np.meshgrid(np.arange(w) + 0.0, np.arange(h) + 0.0)
    d_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    d_W = d_C @ X_WC[:3, :3].T
    origins = np.broadcast_to(X_WC[:3, 3], d_W.shape)
    rays = np.concatenate([origins, d_W], axis=-1).astype(np.float32)
    # With unnormalised directions of unit z, t_hit is the depth along +z_C.
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return np.where(np.isfinite(t), t, 0.0).astype(np.float64)


def make_scan(
    object_name: str = "pebble",
    size_m: float = 0.2,
    directions: np.ndarray | None = None,
    radius_m: float = 0.5,
    image_size: tuple[int, int] = (640, 480),
    focal_px: float = 660.0,
    depth_noise_m: float = 0.0003,
    flange_noise_m: float = 0.00005,
    flange_noise_rad: float = math.radians(0.005),
    handeye_error_m: float = 0.003,
    handeye_error_rad: float = math.radians(1.0),
    seed: int = 0,
) -> SyntheticScan:
    rng = np.random.default_rng(seed)
    mesh = resolve_object(object_name, size_m)
    vertices_W = mesh.vertices + OBJECT_CENTER_W
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(vertices_W.astype(np.float32)),
        o3d.core.Tensor(mesh.triangles.astype(np.uint32)),
    )
    if directions is None:
        directions = cap_directions(12, ROBOT_SIDE, math.radians(35.0))

    X_FC_nominal = nominal_X_FC(0.12)
    axis = rng.standard_normal(3)
    shift = rng.standard_normal(3)
    X_err = make_pose(
        rotation_about(axis, handeye_error_rad),
        handeye_error_m * shift / np.linalg.norm(shift),
    )
    X_FC_true = X_FC_nominal @ X_err

    K = np.array([[focal_px, 0, image_size[0] / 2], [0, focal_px, image_size[1] / 2], [0, 0, 1]])
    views, X_WC_true = [], []
    for i, d in enumerate(directions):
        # Rolls spread over the circle: the camera's free roll is what makes the hand-eye
        # translation observable from a small cap of view directions.
        roll = 2 * math.pi * ((i * 0.381966) % 1.0)
        X_WC = look_at(OBJECT_CENTER_W + radius_m * d, OBJECT_CENTER_W, roll)
        depth = render_depth(scene, X_WC, K, image_size)
        hit = depth > 0
        noisy = np.where(hit, depth + depth_noise_m * rng.standard_normal(depth.shape), 0.0)
        v, u = np.nonzero(hit)
        z = noisy[hit]
        p_C = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
        shade = (128 + 100 * np.sin(transform_points(X_WC, p_C) * 300).sum(axis=1) / 3).clip(0, 255)
        colors = np.repeat(shade[:, None], 3, axis=1).astype(np.uint8)
        X_err_F = twist_to_pose(
            np.concatenate(
                [flange_noise_rad * rng.standard_normal(3), flange_noise_m * rng.standard_normal(3)]
            )
        )
        X_WF = X_WC @ invert(X_FC_true) @ X_err_F
        views.append(ViewCloud(i, p_C, colors, X_WF, DepthImage(noisy.astype(np.float32), K)))
        X_WC_true.append(X_WC)
    return SyntheticScan(views, X_FC_true, X_FC_nominal, X_WC_true, vertices_W, mesh.triangles)

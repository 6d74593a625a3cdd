"""Regions of interest: the window of a pinhole image that holds some geometry, and the camera
that renders only that window.

A frame renders only the window holding the moving geometry over a background rendered once, and
the tool mask only the window holding the tool: a window renders in a fraction of a whole image's
time (robots/simulation/cell_video/video.py).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.geometry import (
    Box,
    ClippingRange,
    ColorRenderCamera,
    Cylinder,
    RenderCameraCore,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.systems.sensors import CameraInfo

from robots.models.workcell import RENDERER_NAME
from robots.simulation.stereo_camera import FAR_CLIP_M, NEAR_CLIP_M

_CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
# A region of interest this large renders hardly faster than the whole image.
MAX_ROI_FRACTION = 0.6


def bounding_radius_m(shape) -> float | None:
    """Radius of a sphere about the shape's origin holding it; None for other shapes."""
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Cylinder):
        return math.hypot(shape.radius(), shape.length() / 2)
    if isinstance(shape, Box):
        return 0.5 * math.sqrt(shape.width() ** 2 + shape.depth() ** 2 + shape.height() ** 2)
    return None


def spheres_roi_px(
    p_S: np.ndarray, radius_m: np.ndarray, K: np.ndarray, size: tuple[int, int], margin_px: int
) -> tuple[int, int, int, int] | None:
    """Pixel box (u0, v0, u1, v1), ends exclusive, of a pinhole image (K, size = (w, h)) that
    holds the images of spheres (centres p_S (N, 3) in the camera frame, radii (N,)) and the
    principal point (Drake's renderer wants it inside every image); None when a sphere reaches
    the camera's plane. The image of a sphere lies within that of its bounding cube."""
    w, h = size
    cx, cy = K[0, 2], K[1, 2]
    lo = np.array([math.floor(cx), math.floor(cy)], float)
    hi = lo + 1
    if len(p_S):
        if np.any(p_S[:, 2] - radius_m < NEAR_CLIP_M):
            return None
        corners = p_S[:, None, :] + radius_m[:, None, None] * _CUBE[None]
        uv = corners[..., :2] / corners[..., 2:3] * [K[0, 0], K[1, 1]] + [cx, cy]
        lo = np.minimum(lo, uv.reshape(-1, 2).min(axis=0))
        hi = np.maximum(hi, uv.reshape(-1, 2).max(axis=0))
    u0, v0 = (max(0, math.floor(x) - margin_px) for x in lo)
    u1, v1 = min(w, math.ceil(hi[0]) + margin_px + 1), min(h, math.ceil(hi[1]) + margin_px + 1)
    return u0, v0, u1, v1


def roi_camera(K: np.ndarray, roi: tuple[int, int, int, int]) -> ColorRenderCamera:
    """The render camera of a sub-window of a pinhole image (same rays: the principal point
    shifts; +0.5 for Drake's pixel-centre convention, as in _RenderedCamera of
    robots/simulation/stereo_camera.py)."""
    u0, v0, u1, v1 = roi
    info = CameraInfo(u1 - u0, v1 - v0, K[0, 0], K[1, 1], K[0, 2] + 0.5 - u0, K[1, 2] + 0.5 - v0)
    core = RenderCameraCore(
        RENDERER_NAME, info, ClippingRange(NEAR_CLIP_M, FAR_CLIP_M), RigidTransform()
    )
    return ColorRenderCamera(core, False)

"""Masks of the cell video: where the robot, its camera tool or the hung object lie in the raw
images, rendered from the scene's label images and dilated by a margin (px).

The masks are what the software knows: the arm at the MEASURED joints and the rig at the
software's pose. CellVideo (robots/simulation/cell_video/video.py) keeps the caches and the
public methods; the rendering is here.
"""

from __future__ import annotations

import cv2
import numpy as np
from pydrake.math import RigidTransform

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.stereo.camera_model import PinholeCamera
from robots.simulation.cell_video.roi import roi_camera, spheres_roi_px
from robots.simulation.cell_video.scene import VideoScene
from robots.simulation.stereo_camera import _RenderedCamera

DEFAULT_MASK_MARGIN_PX = 8


def check_margin(margin_px) -> int:
    if not (isinstance(margin_px, int | np.integer) and 0 <= margin_px <= 200):
        raise ScannerError(f"margin_px: expected an integer in [0, 200], got {margin_px!r}")
    return int(margin_px)


def half_camera(cam: PinholeCamera) -> PinholeCamera:
    """The same lens on a half-resolution sensor (pixel centres at integers, as OpenCV's)."""
    K = cam.K.copy()
    K[:2, :2] /= 2
    K[:2, 2] = (K[:2, 2] + 0.5) / 2 - 0.5
    return PinholeCamera(K, cam.distortion, cam.width // 2, cam.height // 2)


def _dilated(mask: np.ndarray, margin_px: int) -> np.ndarray:
    if margin_px == 0:
        return mask
    size = 2 * margin_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return cv2.dilate(mask, kernel)


def _full_size(half: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A half-resolution mask on the full sensor grid of `size` (w, h) (each half pixel covers
    2x2 full ones)."""
    w, h = size
    return cv2.resize(half, (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def render_half_mask(
    scene: VideoScene,
    context,
    labels: np.ndarray,
    half: _RenderedCamera,
    X_WS: np.ndarray,
    margin_px: int,
    size: tuple[int, int],
) -> np.ndarray:
    """A label set's silhouette in a posed context, rendered at half resolution by `half` (a
    half_camera) from X_WS, dilated by >= margin_px and brought to the full sensor grid of
    `size` (w, h) (each half pixel covers 2x2 full ones). About 4 ms at 640x480."""
    mask = np.isin(scene.labels(context, half, X_WS), labels)
    return _full_size(_dilated(mask.astype(np.uint8), (margin_px + 1) // 2), size)


def _tool_pixels(scene: VideoScene, camera: _RenderedCamera, X_WS: np.ndarray) -> np.ndarray:
    """The posed tool view's silhouette on the sensor grid at full resolution (the tracker
    fits its outline: half resolution doubled its error), rendered in the window holding
    the tool only (half the time of a whole label render)."""
    query = scene.query(scene.tool_view)
    centres = [query.GetPoseInWorld(gid).translation() for gid, _ in scene.tool_spheres]
    radii = np.array([r for _, r in scene.tool_spheres])
    p_S = transform_points(invert(X_WS), np.array(centres))
    K, (w, h) = camera.maps.K_render, camera.maps.render_size
    roi = spheres_roi_px(p_S, radii, K, (w, h), margin_px=2)
    sg = scene.cell.scene_graph
    if roi is None:
        labels = scene.labels(scene.tool_view, camera, X_WS)
    else:
        u0, v0, u1, v1 = roi
        window = query.RenderLabelImage(
            roi_camera(K, roi), sg.world_frame_id(), RigidTransform(X_WS)
        )
        grid = np.full((h, w), -1, np.int32)
        grid[v0:v1, u0:u1] = np.asarray(window.data)[..., 0]
        labels = camera.distort(grid, nearest=True)
    # Every label is the tool's: nothing else has a perception role in this view.
    return np.isin(labels, scene.robot_labels)


def render_tool_mask(
    scene: VideoScene, camera: _RenderedCamera, X_WS: np.ndarray, margin_px: int
) -> np.ndarray:
    """The posed tool view's silhouette seen by `camera` from X_WS, at full resolution, dilated
    by margin_px; read-only. About 5 ms a camera at 640x480."""
    tool = _tool_pixels(scene, camera, X_WS)
    mask = _dilated(tool.astype(np.uint8), margin_px).astype(bool)
    mask.setflags(write=False)
    return mask

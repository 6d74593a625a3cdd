"""Simulated stereo camera: Drake VTK pinhole renders, then the TRUE lens distortion and noise.

Each camera is rendered with a pinhole model wide enough to cover the distorted sensor (barrel
distortion sees further out than a pinhole of the same focal length), then resampled onto the
sensor grid through the distortion model: a sensor pixel's undistorted ray is looked up in the
pinhole render. Undistortion and rectification downstream are thus really exercised.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import cv2
import numpy as np
from pydrake.geometry import (
    ClippingRange,
    ColorRenderCamera,
    DepthRange,
    DepthRenderCamera,
    RenderCameraCore,
)
from pydrake.math import RigidTransform
from pydrake.systems.sensors import CameraInfo

from reconstruction.stereo.camera_model import PinholeCamera
from robots.drivers.interfaces import StereoCameraDriver, StereoImages
from robots.models.workcell import RENDERER_NAME, Workcell
from robots.simulation.truth import Truth

NEAR_CLIP_M = 0.03
FAR_CLIP_M = 5.0


@dataclass(frozen=True, eq=False)
class DistortionMaps:
    """Pinhole render intrinsics and the sensor->render lookup maps of one camera."""

    K_render: np.ndarray
    render_size: tuple[int, int]
    map_x: np.ndarray
    map_y: np.ndarray


def undistorted_normalised(cam: PinholeCamera, pixels: np.ndarray) -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 2) ideal normalised coordinates (x/z, y/z), converged."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    pts = cv2.undistortPointsIter(
        pixels.reshape(-1, 1, 2).astype(np.float64), cam.K, cam.distortion, None, None, criteria
    )
    return pts.reshape(-1, 2)


def distortion_maps(cam: PinholeCamera, margin_px: int = 4) -> DistortionMaps:
    """The pinhole render that covers the distorted sensor, and the sensor->render lookup."""
    key = (cam.K.tobytes(), cam.distortion.tobytes(), cam.width, cam.height, margin_px)
    with _maps_lock:
        if key not in _maps_made:
            if len(_maps_made) >= 4:
                _maps_made.pop(next(iter(_maps_made)))
            maps = _distortion_maps(cam, margin_px)
            for shared in (maps.K_render, maps.map_x, maps.map_y):
                shared.flags.writeable = False
            _maps_made[key] = maps
        return _maps_made[key]


# A simulation builds its cameras anew at every re-hang and in every test: the lookup (about
# 0.8 s per camera, one iterative undistortion per pixel) is the same for the same camera.
_maps_made: dict[tuple, DistortionMaps] = {}
_maps_lock = threading.Lock()


def _distortion_maps(cam: PinholeCamera, margin_px: int) -> DistortionMaps:
    u, v = np.meshgrid(
        np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64)
    )
    xy = undistorted_normalised(cam, np.stack([u.ravel(), v.ravel()], axis=1))
    f = cam.K[0, 0], cam.K[1, 1]
    x_px, y_px = xy[:, 0] * f[0], xy[:, 1] * f[1]
    cx = -x_px.min() + margin_px
    cy = -y_px.min() + margin_px
    width = int(np.ceil(x_px.max() + cx + margin_px))
    height = int(np.ceil(y_px.max() + cy + margin_px))
    K_render = np.array([[f[0], 0, cx], [0, f[1], cy], [0, 0, 1]])
    map_x = (x_px + cx).reshape(cam.height, cam.width).astype(np.float32)
    map_y = (y_px + cy).reshape(cam.height, cam.width).astype(np.float32)
    return DistortionMaps(K_render, (width, height), map_x, map_y)


@dataclass(frozen=True, eq=False)
class CameraGroundTruth:
    """A perfect left sensor's view: z-depth (m, inf = nothing) and the object mask."""

    depth_m: np.ndarray
    object_mask: np.ndarray
    X_WC: np.ndarray


class _RenderedCamera:
    def __init__(self, cam: PinholeCamera) -> None:
        self.cam = cam
        self.maps = distortion_maps(cam)
        K = self.maps.K_render
        w, h = self.maps.render_size
        # Drake puts pixel centres at half-integers (the image's top-left corner is (0, 0)),
        # OpenCV at integers: the same ray is 0.5 px further right and down in Drake's numbers.
        # Without the shift every rendered image sits 0.5 px up-left of where the true camera
        # model projects (measured on a calibration board: -0.47 px in u and v).
        core = RenderCameraCore(
            RENDERER_NAME,
            CameraInfo(w, h, K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5),
            ClippingRange(NEAR_CLIP_M, FAR_CLIP_M),
            RigidTransform(),
        )
        self.color = ColorRenderCamera(core, False)
        self.depth = DepthRenderCamera(core, DepthRange(NEAR_CLIP_M + 0.01, FAR_CLIP_M - 0.01))

    def distort(self, image: np.ndarray, nearest: bool = False) -> np.ndarray:
        interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        return cv2.remap(
            image, self.maps.map_x, self.maps.map_y, interp, borderMode=cv2.BORDER_REPLICATE
        )


class SimulatedStereoCamera(StereoCameraDriver):
    """Renders the pair seen from the TRUE camera pose at the robot's TRUE configuration."""

    def __init__(self, workcell: Workcell, truth: Truth, true_joint_positions) -> None:
        if not workcell.has_renderer:
            raise ValueError("the simulated camera needs a work cell built with renderer=True")
        self._cell = workcell
        self._truth = truth
        self._true_q = true_joint_positions
        self._left = _RenderedCamera(truth.stereo.left)
        self._right = _RenderedCamera(truth.stereo.right)
        self._X_CR = truth.stereo.X_CR
        self._context = workcell.diagram.CreateDefaultContext()
        self._captures = 0

    def true_X_WC(self) -> np.ndarray:
        plant = self._cell.plant
        plant_context = plant.GetMyContextFromRoot(self._context)
        plant.SetPositions(plant_context, self._cell.robot, self._true_q())
        flange = plant.GetFrameByName(self._cell.flange_frame, self._cell.robot)
        return flange.CalcPoseInWorld(plant_context).GetAsMatrix4() @ self._truth.X_FC

    def _query(self):
        sg = self._cell.scene_graph
        return sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self._context)), sg

    def _render_rgb(self, camera: _RenderedCamera, X_WS: np.ndarray) -> np.ndarray:
        query, sg = self._query()
        image = query.RenderColorImage(camera.color, sg.world_frame_id(), RigidTransform(X_WS))
        return camera.distort(np.array(image.data)[..., :3])

    def _noisy(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self._truth.image_noise_std <= 0:
            return image
        # float32 throughout: a third of the time of float64 noise on two 1280x960 images
        # per view, for values that end as whole grey levels anyway.
        noisy = rng.standard_normal(image.shape, dtype=np.float32)
        noisy *= self._truth.image_noise_std
        noisy += image
        # + 0.5: the cast truncates, and a sensor rounds (else every image is 0.5 level dark).
        noisy += 0.5
        np.clip(noisy, 0, 255, out=noisy)
        return noisy.astype(np.uint8)

    def capture(self) -> StereoImages:
        X_WC = self.true_X_WC()
        rng = np.random.default_rng([self._truth.seed, self._captures])
        self._captures += 1
        left = self._noisy(self._render_rgb(self._left, X_WC), rng)
        right = self._noisy(self._render_rgb(self._right, X_WC @ self._X_CR), rng)
        return StereoImages(left, right, stamp_s=time.time())

    def ground_truth(self) -> CameraGroundTruth:
        """True depth and object mask on the LEFT sensor grid (distorted, like the images)."""
        X_WC = self.true_X_WC()
        query, sg = self._query()
        X = RigidTransform(X_WC)
        depth = np.array(query.RenderDepthImage(self._left.depth, sg.world_frame_id(), X).data)
        labels = np.array(query.RenderLabelImage(self._left.color, sg.world_frame_id(), X).data)
        depth = self._left.distort(depth[..., 0].astype(np.float32), nearest=True)
        mask = self._left.distort(
            (labels[..., 0] == self._cell.object_label()).astype(np.uint8), nearest=True
        ).astype(bool)
        return CameraGroundTruth(depth, mask, X_WC)


def render_overview(
    workcell: Workcell,
    q: np.ndarray,
    X_WV: np.ndarray,
    width: int = 960,
    height: int = 720,
    focal_px: float = 700.0,
) -> np.ndarray:
    """An undistorted RGB picture of the cell from viewer pose X_WV (for people, not for stereo)."""
    context = workcell.diagram.CreateDefaultContext()
    plant = workcell.plant
    plant.SetPositions(plant.GetMyContextFromRoot(context), workcell.robot, q)
    core = RenderCameraCore(
        RENDERER_NAME,
        CameraInfo(width, height, focal_px, focal_px, width / 2, height / 2),
        ClippingRange(0.05, 20.0),
        RigidTransform(),
    )
    sg = workcell.scene_graph
    query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(context))
    image = query.RenderColorImage(
        ColorRenderCamera(core, False), sg.world_frame_id(), RigidTransform(X_WV)
    )
    return np.array(image.data)[..., :3]

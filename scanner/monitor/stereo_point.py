"""The static rig's geometry: world points to pixels and matched pixels back to world points.

S is the rig's left optical frame (OpenCV: +z forward, +x right, +y down), posed at X_WS in the
world. Pixels are in the ORIGINAL (distorted) images unless named `_rect`; the rectified frame is
the one cv2.stereoRectify defines (p_rect = R1 @ p_S), where a point's right-image column is its
left column minus its disparity.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.stereo.camera_model import StereoCamera, project_points
from reconstruction.stereo.cloud import points_from_disparity
from reconstruction.stereo.rectification import Rectification, compute_rectification


def _pose(X, name: str) -> np.ndarray:
    X = np.array(X, dtype=float)
    if X.shape != (4, 4) or not np.all(np.isfinite(X)):
        raise ScannerError(f"{name}: expected a finite 4x4 pose, got shape {X.shape}")
    if not np.allclose(X[:3, :3] @ X[:3, :3].T, np.eye(3), atol=1e-6):
        raise ScannerError(f"{name}: the rotation part is not a rotation matrix")
    X.setflags(write=False)
    return X


@dataclass(frozen=True, eq=False)
class StereoRig:
    """A calibrated static stereo pair at X_WS, with its rectification computed once."""

    camera: StereoCamera
    X_WS: np.ndarray
    rect: Rectification

    @classmethod
    def create(cls, camera: StereoCamera, X_WS: np.ndarray) -> StereoRig:
        # alpha = 1 keeps every source pixel: an intruder enters at the image border, which the
        # alpha = 0 crop of a distorted lens would cut away.
        return cls(camera, _pose(X_WS, "X_WS"), compute_rectification(camera, alpha=1.0))

    @property
    def X_SW(self) -> np.ndarray:
        return invert(self.X_WS)

    @property
    def image_size(self) -> tuple[int, int]:
        return self.camera.image_size


def project_W(rig: StereoRig, p_W: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points p_W (N, 3) -> left pixels (N, 2), right pixels (N, 2), depth in S (N,) in metres.
    Pixels of points behind the camera are meaningless; check the depth."""
    p_S = transform_points(rig.X_SW, np.atleast_2d(np.asarray(p_W, float)))
    p_R = p_S @ rig.camera.R.T + rig.camera.T
    return project_points(rig.camera.left, p_S), project_points(rig.camera.right, p_R), p_S[:, 2]


def rectify_pixels(rig: StereoRig, uv: np.ndarray, side: str) -> np.ndarray:
    """Original pixels (N, 2) of the `side` ('left' or 'right') image -> rectified pixels (N, 2)."""
    cam, R, P = {
        "left": (rig.camera.left, rig.rect.R1, rig.rect.P1),
        "right": (rig.camera.right, rig.rect.R2, rig.rect.P2),
    }[side]
    uv = np.asarray(uv, np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(uv, cam.K, cam.distortion, R=R, P=P).reshape(-1, 2)


def lift_rectified_W(rig: StereoRig, uvd_rect: np.ndarray) -> np.ndarray:
    """Rectified left pixels with disparities (N, 3) (u, v, d) -> world points (N, 3)."""
    return transform_points(rig.X_WS, points_from_disparity(rig.rect, uvd_rect))


@dataclass(frozen=True)
class Triangulation:
    """A matched pixel pair lifted to the world: p_W (m), the disparity and the vertical
    mismatch of the rectified pixels (px; near 0 for a true correspondence)."""

    p_W: np.ndarray
    disparity_px: float
    epipolar_error_px: float


def triangulate_W(rig: StereoRig, uv_left: np.ndarray, uv_right: np.ndarray) -> Triangulation:
    """One point seen at original pixel uv_left in the left and uv_right in the right image."""
    ql = rectify_pixels(rig, uv_left, "left")[0]
    qr = rectify_pixels(rig, uv_right, "right")[0]
    d = float(ql[0] - qr[0])
    # Both rows carry the point's height; their mean halves the noise of either one.
    v = 0.5 * (ql[1] + qr[1])
    p_W = lift_rectified_W(rig, np.array([[ql[0], v, d]]))[0]
    return Triangulation(p_W, d, float(abs(ql[1] - qr[1])))


def disparity_range(
    rig: StereoRig, box_min_W, box_max_W, min_depth_m: float
) -> tuple[float, float]:
    """The disparities (px, rectified pair) of an axis-aligned world box's corners; depths below
    min_depth_m (corners near or behind the camera) count as min_depth_m."""
    corners_W = np.array(
        [
            [x, y, z]
            for x in (box_min_W[0], box_max_W[0])
            for y in (box_min_W[1], box_max_W[1])
            for z in (box_min_W[2], box_max_W[2])
        ]
    )
    p_rect = transform_points(rig.X_SW, corners_W) @ rig.rect.R1.T
    z = np.maximum(p_rect[:, 2], min_depth_m)
    fb = rig.rect.focal_px * rig.rect.baseline_m
    d = fb / z
    return float(d.min()), float(d.max())

"""Synthetic stereo frames of a cell with known geometry, for the monitor's tests.

A distortion-free rig (640x480, f 640 px, b 0.25 m, the static cell camera's optics) looks along
the world's -x axis from (2, 0, 0.8): a world point at x_W lies at depth 2 - x_W in the rig's left
frame S. The far wall is a textured plane at 3.2 m (disparity 50 px); objects are fronto-parallel
textured discs at known centres, drawn at their true disparity f b / z in the right image, so
the ground truth of every pixel is known. Each frame gets its own sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.transforms import invert, make_pose, transform_points
from reconstruction.stereo.camera_model import default_stereo_camera
from scanner.monitor.stereo_point import StereoRig

W, H = 640, 480
FOCAL_PX = 640.0
BASELINE_M = 0.25
WALL_DEPTH_M = 3.2
NOISE_STD = 2.0
P_W_RIG = np.array([2.0, 0.0, 0.8])


def rig() -> StereoRig:
    camera = default_stereo_camera(W, H, FOCAL_PX, BASELINE_M, (0.0, 0.0, 0.0, 0.0, 0.0))
    z = np.array([-1.0, 0.0, 0.0])
    x = np.cross(z, [0.0, 0.0, 1.0])
    R_WS = np.column_stack([x, np.cross(z, x), z])
    return StereoRig.create(camera, make_pose(R_WS, P_W_RIG))


def _texture(rng: np.random.Generator, h: int, w: int, mean: float, contrast: float) -> np.ndarray:
    noise = rng.standard_normal((h, w)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 1.5)
    return mean + contrast * smooth / smooth.std()


@dataclass(frozen=True)
class Disc:
    """A fronto-parallel textured disc: centre p_W (m), radius (m), mean grey."""

    p_W: tuple[float, float, float]
    radius_m: float
    grey: float = 170.0


class Scene:
    """Renders left/right grey frames of the wall plus discs and rectangles (robot stand-ins)."""

    def __init__(self, seed: int = 0) -> None:
        self.rig = rig()
        self.rng = np.random.default_rng(seed)
        d_wall = round(FOCAL_PX * BASELINE_M / WALL_DEPTH_M)
        self._wall = _texture(self.rng, H, W + d_wall, 110.0, 30.0)
        self._d_wall = d_wall
        self._disc_tex = _texture(self.rng, 401, 401, 0.0, 35.0)
        self._rect_tex = _texture(self.rng, H, W, 60.0, 40.0)

    def pixel(self, p_W) -> tuple[np.ndarray, float]:
        """Left pixel (u, v) and disparity (px) of a world point."""
        p_S = transform_points(invert(self.rig.X_WS), np.atleast_2d(p_W))[0]
        K = self.rig.camera.left.K
        uv = np.array([K[0, 0] * p_S[0] / p_S[2] + K[0, 2], K[1, 1] * p_S[1] / p_S[2] + K[1, 2]])
        return uv, FOCAL_PX * BASELINE_M / p_S[2]

    def _draw_disc(self, left, right, disc: Disc) -> np.ndarray:
        (u, v), d = self.pixel(disc.p_W)
        z = FOCAL_PX * BASELINE_M / d
        r = FOCAL_PX * disc.radius_m / z
        mask_left = None
        for image, uc in ((left, u), (right, u - d)):
            yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
            du, dv = xx - uc, yy - v
            inside = du * du + dv * dv <= r * r
            tex = self._disc_tex[
                np.clip(np.round(dv + 200).astype(int), 0, 400),
                np.clip(np.round(du + 200).astype(int), 0, 400),
            ]
            image[inside] = disc.grey + tex[inside]
            if mask_left is None:
                mask_left = inside
        return mask_left

    def frame(
        self, discs=(), rects=()
    ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """Grey uint8 left and right images, the left masks of the discs and of the rectangles.
        rects: (x, y, w, h) left-image rectangles with a texture fixed to the image (a robot
        link whose surface pattern moves with it is no harder: it is masked either way)."""
        left = self._wall[:, self._d_wall :].copy()
        right = self._wall[:, :W].copy()
        rect_masks = []
        for x, y, w, h in rects:
            m = np.zeros((H, W), bool)
            m[max(0, y) : y + h, max(0, x) : x + w] = True
            tex = np.roll(self._rect_tex, (y, x), axis=(0, 1))
            left[m] = tex[m]
            # The right view of a link 1.5 m away: shifted by its disparity.
            mr = np.roll(m, -107, axis=1)
            right[mr] = np.roll(tex, -107, axis=1)[mr]
            rect_masks.append(m)
        disc_masks = [self._draw_disc(left, right, disc) for disc in discs]
        out = []
        for image in (left, right):
            noisy = image + self.rng.standard_normal(image.shape, dtype=np.float32) * NOISE_STD
            out.append(np.clip(noisy, 0, 255).astype(np.uint8))
        return out[0], out[1], disc_masks, rect_masks

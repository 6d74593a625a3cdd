"""Simulated depth (RGB-D) camera: Drake renders of the TRUE device at the robot's TRUE pose,
then the errors of an active infrared stereo depth camera (an Intel RealSense D400-class device).

Per capture: one colour render with the colour camera at X_WC (with the stereo camera's sensor
noise), one depth render and one colour render (its grey level: where the projector's pattern
is absorbed) with the depth camera at X_WD = X_WC @ X_CD, then `noisy_depth_counts`, a pure
function of the true depth, so the noise model is tested without Drake.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from pydrake.math import RigidTransform

from reconstruction.common.checks import check_fields, fraction, non_negative, positive
from robots.drivers.interfaces import DepthCameraDriver, RgbdImages
from robots.models.workcell import Workcell
from robots.simulation.stereo_camera import SimulatedStereoCamera, _RenderedCamera
from robots.simulation.truth import Truth


@dataclass(frozen=True)
class DepthNoise:
    """The depth errors of an active stereo depth camera (pixels, metres, degrees, 0-255)."""

    # Axial RMS = subpixel_px * z^2 / (f_px * baseline_m): Intel, Grunnet-Jepsen et al.,
    # "Best-Known-Methods for Tuning Intel RealSense D400 Depth Cameras for Best Performance"
    # (white paper): subpixel about 0.08 for a well-textured target with the projector on.
    subpixel_px: float = non_negative(0.08)
    # Modelling choice: each pixel's depth is the surface seen a Gaussian 0.25 px (std, per
    # axis) beside it (where the matching window's support lands), which moves depth edges
    # sideways.
    lateral_px: float = non_negative(0.25)
    # Modelling choice: stereo matching fails on strongly foreshortened texture; surfaces seen
    # more than this from face-on give no depth.
    grazing_max_deg: float = positive(75.0, at_most=90.0)
    # Modelling choice: dark surfaces absorb the projector's infrared pattern; pixels darker
    # than dark_grey (8-bit grey at the depth camera) lose their depth with probability
    # dark_drop.
    dark_grey: float = non_negative(20.0)
    dark_drop: float = fraction(0.5)
    # Modelling choice: where a pixel's depth differs from a 4-neighbour's by more than
    # edge_jump_m, with probability flying_share it reports a random mix of the two (a matching
    # window straddling a depth edge).
    edge_jump_m: float = positive(0.02)
    flying_share: float = fraction(0.3)

    def __post_init__(self) -> None:
        check_fields("depth_noise", self)


def depth_rms_m(z_m: np.ndarray | float, f_px: float, baseline_m: float, subpixel_px: float):
    """The axial depth RMS error (m) at depth z_m (Intel's D400 white paper, see DepthNoise)."""
    return subpixel_px * np.square(z_m) / (f_px * baseline_m)


def noisy_depth_counts(
    true_depth_m: np.ndarray,
    grey: np.ndarray,
    f_px: float,
    baseline_m: float,
    depth_scale_m: float,
    depth_scale_error: float,
    min_depth_m: float,
    max_depth_m: float,
    noise: DepthNoise,
    rng: np.random.Generator,
    principal_px: tuple[float, float] | None = None,
) -> np.ndarray:
    """The (H, W) uint16 depth counts a device reports for the true z-depth `true_depth_m`
    (0, NaN or inf: no surface) seen with grey levels `grey` (H, W; 0-255). Reported depth =
    noisy true depth / (1 + depth_scale_error), in counts of depth_scale_m; 0 = no depth.
    `principal_px` (u, v): the depth camera's principal point for the viewing rays (default
    the image centre, OpenCV convention).

    Order: holes from the clean geometry and image (grazing surfaces, dark spots), lateral
    jitter, flying pixels at the jittered depth edges, axial noise, the scale error, whole
    depth units, the range."""
    h, w = true_depth_m.shape
    z = np.asarray(true_depth_m, np.float32)
    z = np.where(np.isfinite(z) & (z > 0), z, np.float32(0))
    cx, cy = ((w - 1) / 2, (h - 1) / 2) if principal_px is None else principal_px

    # Normals from the clean depth: the jitter's repeated or skipped pixels would bend them.
    holes = _grazing(z, f_px, cx, cy, noise.grazing_max_deg)
    dark = np.flatnonzero((np.asarray(grey) < noise.dark_grey) & (z > 0))
    holes.ravel()[dark[rng.random(dark.size) < noise.dark_drop]] = True

    z = _jittered(z, noise.lateral_px, rng)
    z = _flying(z, noise.edge_jump_m, noise.flying_share, rng)
    z[holes] = 0

    seen = z > 0
    zs = z[seen]
    zs += depth_rms_m(zs, f_px, baseline_m, noise.subpixel_px) * rng.standard_normal(
        zs.size, dtype=np.float32
    )
    # The device reports depth / (1 + e); counts are whole depth units.
    reported = np.rint(zs / np.float32((1 + depth_scale_error) * depth_scale_m))
    reported_m = reported.astype(np.float64) * depth_scale_m
    in_range = (reported_m >= min_depth_m) & (reported_m <= max_depth_m) & (reported <= 65535)
    counts = np.zeros((h, w), np.uint16)
    counts[seen] = np.where(in_range, reported, 0).astype(np.uint16)
    return counts


def _grazing(z: np.ndarray, f_px: float, cx: float, cy: float, max_deg: float) -> np.ndarray:
    """Pixels whose surface normal is more than max_deg from the viewing ray.

    The surface's tangents are the back-projected points' differences to a neighbour,
    p_DQ' - p_DQ = a r + b e (r = (x, y, 1) the pixel's ray, e the image axis, a the signed
    depth step, b the neighbour's depth / f), taken on the smoother side (the smaller depth
    step), so a depth edge does not read as a steep surface. Then n = t_u x t_v has
    n.r = b_u b_v and the components below (a few 2-D arrays instead of 3-vectors per pixel).
    The rays are a pinhole's: lens distortion of the depth image is neglected here (the
    designed device's depth camera has none)."""
    h, w = z.shape
    x = ((np.arange(w, dtype=np.float32) - np.float32(cx)) / np.float32(f_px))[None, :]
    y = ((np.arange(h, dtype=np.float32) - np.float32(cy)) / np.float32(f_px))[:, None]
    a_u, b_u = _smooth_side_step(z, 1, f_px)
    a_v, b_v = _smooth_side_step(z, 0, f_px)
    n_x, n_y = a_u * b_v, b_u * a_v
    n_z = n_x * x + n_y * y + b_u * b_v
    n_sq = n_x**2 + n_y**2 + n_z**2
    cos_sq = np.float32(np.cos(np.radians(max_deg)) ** 2)
    grazing = (b_u * b_v) ** 2 < cos_sq * n_sq * (x**2 + y**2 + 1)
    return grazing & (z > 0)


def _smooth_side_step(z: np.ndarray, axis: int, f_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) of the step to the next or previous pixel along `axis`, whichever has the smaller
    depth step among those to a surface; with neither, a fronto-parallel step (a = 0)."""
    padded = np.pad(z, [(1, 1) if k == axis else (0, 0) for k in range(2)])
    ahead = padded[2:] if axis == 0 else padded[:, 2:]
    behind = padded[:-2] if axis == 0 else padded[:, :-2]
    inf = np.float32(np.inf)
    step_ahead = np.where(ahead > 0, np.abs(ahead - z), inf)
    step_behind = np.where(behind > 0, np.abs(z - behind), inf)
    use_ahead = step_ahead <= step_behind
    a = np.where(use_ahead, ahead - z, z - behind)
    nb = np.where(use_ahead, ahead, behind)
    neither = np.isinf(np.minimum(step_ahead, step_behind))
    a[neither] = 0
    nb[neither] = z[neither]
    return a, nb / np.float32(f_px)


def _jittered(z: np.ndarray, lateral_px: float, rng: np.random.Generator) -> np.ndarray:
    """Each pixel's depth taken at a Gaussian-jittered position (nearest pixel: an edge moves
    sideways rather than blending)."""
    if lateral_px <= 0:
        return z.copy()
    h, w = z.shape
    jitter = rng.standard_normal((2, h, w), dtype=np.float32) * np.float32(lateral_px)
    jitter[0] += np.arange(w, dtype=np.float32)[None, :]
    jitter[1] += np.arange(h, dtype=np.float32)[:, None]
    return cv2.remap(z, jitter[0], jitter[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)


def _flying(
    z: np.ndarray, edge_jump_m: float, share: float, rng: np.random.Generator
) -> np.ndarray:
    """At depth edges between two surfaces, `share` of the pixels report a random mix of their
    depth and a neighbour's across the edge."""
    h, w = z.shape
    padded = np.pad(z, 1)
    other = np.zeros_like(z)
    for dv, du in ((0, -1), (0, 1), (-1, 0), (1, 0)):
        nb = padded[1 + dv : 1 + dv + h, 1 + du : 1 + du + w]
        edge = (other == 0) & (z > 0) & (nb > 0) & (np.abs(nb - z) > edge_jump_m)
        other[edge] = nb[edge]
    candidates = np.flatnonzero(other)
    fly = candidates[rng.random(candidates.size) < share]
    out = z.copy()
    mix = rng.random(fly.size, dtype=np.float32)
    out.ravel()[fly] += mix * (other.ravel()[fly] - z.ravel()[fly])
    return out


@dataclass(frozen=True, eq=False)
class DepthGroundTruth:
    """A perfect depth camera's view on the depth grid: z-depth (m, inf or 0 = nothing), the
    object mask, and the true colour (X_WC) and depth (X_WD) camera poses."""

    depth_m: np.ndarray
    object_mask: np.ndarray
    X_WC: np.ndarray
    X_WD: np.ndarray


class SimulatedDepthCamera(DepthCameraDriver):
    """Renders the true RGB-D device (truth.rgbd) at the robot's TRUE configuration."""

    def __init__(
        self,
        workcell: Workcell,
        truth: Truth,
        true_joint_positions: Callable[[], np.ndarray],
        baseline_m: float,
        noise: DepthNoise = DepthNoise(),  # noqa: B008 (a frozen dataclass)
    ) -> None:
        if truth.rgbd is None:
            raise ValueError("the simulated depth camera needs truth.rgbd (the true device)")
        if not workcell.has_renderer:
            raise ValueError("the simulated camera needs a work cell built with renderer=True")
        self._cell = workcell
        self._truth = truth
        self._true_q = true_joint_positions
        self._baseline_m = float(baseline_m)
        self._noise = noise
        self._color = _RenderedCamera(truth.rgbd.color)
        # The depth camera's render cameras: depth, and colour (for the grey level there).
        self._depth = _RenderedCamera(truth.rgbd.depth)
        self._context = workcell.diagram.CreateDefaultContext()
        self._captures = 0

    # The stereo camera's pose, render and sensor-noise code, shared as is: these read only
    # _cell, _truth, _true_q and _context, which this class holds under the same names.
    true_X_WC = SimulatedStereoCamera.true_X_WC
    _query = SimulatedStereoCamera._query
    _render_rgb = SimulatedStereoCamera._render_rgb
    _noisy = SimulatedStereoCamera._noisy

    def _render_depth(self, X_WD: np.ndarray) -> np.ndarray:
        query, sg = self._query()
        image = query.RenderDepthImage(self._depth.depth, sg.world_frame_id(), RigidTransform(X_WD))
        return self._depth.distort(np.array(image.data)[..., 0], nearest=True)

    def capture(self) -> RgbdImages:
        rgbd = self._truth.rgbd
        X_WC = self.true_X_WC()
        X_WD = X_WC @ rgbd.X_CD
        rng = np.random.default_rng([self._truth.seed, self._captures])
        self._captures += 1
        color = self._noisy(self._render_rgb(self._color, X_WC), rng)
        grey = cv2.cvtColor(self._render_rgb(self._depth, X_WD), cv2.COLOR_RGB2GRAY)
        K = rgbd.depth.K
        counts = noisy_depth_counts(
            self._render_depth(X_WD),
            grey,
            float(K[0, 0]),
            self._baseline_m,
            rgbd.depth_scale_m,
            self._truth.depth_scale_error,
            rgbd.min_depth_m,
            rgbd.max_depth_m,
            self._noise,
            rng,
            principal_px=(float(K[0, 2]), float(K[1, 2])),
        )
        return RgbdImages(counts, rgbd.depth_scale_m, color, stamp_s=time.time())

    def ground_truth(self) -> DepthGroundTruth:
        """True depth (m) and object mask on the depth camera's grid."""
        X_WC = self.true_X_WC()
        X_WD = X_WC @ self._truth.rgbd.X_CD
        query, sg = self._query()
        labels = query.RenderLabelImage(
            self._depth.color, sg.world_frame_id(), RigidTransform(X_WD)
        )
        is_object = np.array(labels.data)[..., 0] == self._cell.object_label()
        mask = self._depth.distort(is_object.astype(np.uint8), nearest=True).astype(bool)
        return DepthGroundTruth(self._render_depth(X_WD), mask, X_WC, X_WD)

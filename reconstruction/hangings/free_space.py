"""The free-space test of a pass alignment: a pass's points, placed by a hypothesis, must not lie
in space the reference views saw through (in front of what a reference camera measured along
that ray). A wrong turn that fits the shape's overlap still puts points there."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from reconstruction.common.transforms import invert, transform_points
from reconstruction.registration.views import DepthImage


@dataclass(frozen=True)
class SeenSpace:
    """What the reference views saw: their depth images and camera poses in the reference
    frame (for the free-space test)."""

    depths: tuple[DepthImage, ...]
    X_WC: tuple[np.ndarray, ...]
    # The depth images as the test reads them (`_smooth_depth`), made once: every hypothesis
    # of an alignment is tested against the same views (17 x 24 images took 8 s a pass).
    _smoothed: dict = field(default_factory=dict, compare=False, repr=False)

    def smoothed(self, jump_m: float) -> tuple[np.ndarray, ...]:
        if jump_m not in self._smoothed:
            self._smoothed[jump_m] = tuple(_smooth_depth(d, jump_m) for d in self.depths)
        return self._smoothed[jump_m]


def _smooth_depth(depth: DepthImage, jump_m: float) -> np.ndarray:
    """The depth with pixels near a depth discontinuity or a hole zeroed: a ray through a
    silhouette pixel may have measured the surface behind, which proves nothing."""
    import cv2

    d = depth.depth_m
    kernel = np.ones((5, 5), np.uint8)
    high = cv2.dilate(np.where(d > 0, d, 0).astype(np.float32), kernel)
    low = cv2.erode(np.where(d > 0, d, np.inf).astype(np.float32), kernel)
    return np.where((d > 0) & (high - low < jump_m), d, 0)


def free_space_violation(points_W: np.ndarray, seen: SeenSpace, margin_m: float) -> float:
    """The share of (point, reference view) tests in which the point lies more than
    `margin_m` in front of the smooth surface that view measured along its ray: space the view
    saw through. Points behind (occluded) or off the image are not tested."""
    violated = tested = 0
    for depth, X_WC, smooth in zip(seen.depths, seen.X_WC, seen.smoothed(2 * margin_m)):
        p = transform_points(invert(X_WC @ depth.X_CD), points_W)
        p = p[p[:, 2] > 1e-3]
        uv = (p @ depth.K.T)[:, :2] / p[:, 2:3]
        h, w = smooth.shape
        u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        measured = smooth[v[inside], u[inside]]
        has = measured > 0
        z = p[inside][has, 2]
        tested += int(has.sum())
        violated += int(np.sum(z < measured[has] - margin_m))
    return violated / max(tested, 1)

"""Masks that reject unreliable disparities: weak texture, disparity jumps, left-right mismatch.

SGBM's smoothness term propagates a textured object's disparity into the untextured background
next to it (measured on the simulator: 26-46 % of background pixels get object-like depths),
which would grow a "skirt" around every silhouette. These pure functions build boolean masks
(True = keep) on the rectified left grid; `reconstruction.stereo.matching` applies them.
"""

from __future__ import annotations

import cv2
import numpy as np


def texture_mask(grey: np.ndarray, window_px: int, min_std_levels: float) -> np.ndarray:
    """Pixels whose every window_px neighbour has a grey-level std above min_std_levels.

    The std is taken over window_px squares. A patch of sky or flat paint has a std of about the
    sensor noise (2 levels in the simulator); SGBM cannot localise a match there, so whatever it
    reports comes from its neighbours. Background pixels just outside a silhouette have texture
    in their window (the object's edge) but are exactly where SGBM's foreground fattening puts
    object disparities, so the mask is then eroded by half a window: pixels next to a featureless
    region go too, while the object's own rim (whose neighbours all see its texture) stays.
    """
    g = grey.astype(np.float32)
    size = (window_px, window_px)
    mean = cv2.boxFilter(g, -1, size, borderType=cv2.BORDER_REPLICATE)
    mean_sq = cv2.sqrBoxFilter(g, -1, size, borderType=cv2.BORDER_REPLICATE)
    textured = ((mean_sq - mean * mean) > min_std_levels * min_std_levels).astype(np.uint8)
    return cv2.erode(textured, np.ones(size, np.uint8)).astype(bool)


def jump_mask(disparity: np.ndarray, window_px: int, max_jump_px: float) -> np.ndarray:
    """Valid pixels whose valid window_px neighbours span at most max_jump_px of disparity.

    At a depth step SGBM blurs the two surfaces into each other over about half a block, giving
    points floating between them; both sides of a step lose half a window. Invalid neighbours
    are ignored (holes are not steps).
    """
    kernel = np.ones((window_px, window_px), np.uint8)
    valid = np.isfinite(disparity)
    high = cv2.dilate(np.where(valid, disparity, -np.inf).astype(np.float32), kernel)
    low = cv2.erode(np.where(valid, disparity, np.inf).astype(np.float32), kernel)
    with np.errstate(invalid="ignore", over="ignore"):
        return valid & ((high - low) <= max_jump_px)


def left_right_mask(
    disparity_left: np.ndarray, disparity_right: np.ndarray, max_diff_px: float
) -> np.ndarray:
    """Left pixels whose match in the right image points back to them within max_diff_px.

    disparity_right is right-referenced: right pixel x matches left pixel x + d (positive d).
    """
    height, width = disparity_left.shape
    valid = np.isfinite(disparity_left)
    v, u = np.nonzero(valid)
    u_right = np.rint(u - disparity_left[v, u]).astype(np.int64)
    inside = (u_right >= 0) & (u_right < width)
    back = np.full(u.shape, np.nan, np.float32)
    back[inside] = disparity_right[v[inside], u_right[inside]]
    with np.errstate(invalid="ignore"):
        agree = np.abs(back - disparity_left[v, u]) <= max_diff_px
    keep = np.zeros((height, width), bool)
    keep[v[agree], u[agree]] = True
    return keep

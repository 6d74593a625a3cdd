"""Masks that reject unreliable disparities: unsupported weak texture, disparity jumps,
left-right mismatch.

SGBM's smoothness term propagates a textured object's disparity into the untextured background
next to it (measured on the simulator: 26-46 % of background pixels get object-like depths),
which would grow a "skirt" around every silhouette. But smooth real surfaces (a poster, a
painted wall, Middlebury's Venus planes: grey-level std below 1 over 9x9) get their right
disparity the same way, from their textured borders. The difference is support: a smooth real
surface is framed by texture at its own depth, so its disparity continues that of the textured
pixels on both sides along a row or a column (`enclosed_mask`), and most of the smooth region
is framed so; a skirt hangs off the object on one side only and belongs to a large background
region that is mostly unframed (`supported_low_texture`). These pure functions build boolean
masks (True = keep) on the rectified left grid; `reconstruction.stereo.matching` applies them.
"""

from __future__ import annotations

import cv2
import numpy as np


def texture_mask(
    grey: np.ndarray, window_px: int, min_std_levels: float, erode: bool = True
) -> np.ndarray:
    """Pixels whose every window_px neighbour has a grey-level std above min_std_levels
    (erode=False: whose own window has).

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
    if not erode:
        return textured.astype(bool)
    return cv2.erode(textured, np.ones(size, np.uint8)).astype(bool)


def _framed_along_rows(disparity: np.ndarray, anchors: np.ndarray, tolerance_px: float):
    """Pixels with an anchor on both sides in their row, reached without crossing a pixel
    without disparity (a gap in the data may be background seen between two parts of the
    object), whose disparity is within tolerance_px of the straight line between the two
    anchors' disparities (a plane seen in perspective has a disparity linear in the image)."""
    height, width = disparity.shape
    # 32-bit throughout: half the memory traffic of numpy's default 64-bit (this runs on
    # every pixel of every view, twice).
    disparity = disparity.astype(np.float32, copy=False)
    column = np.broadcast_to(np.arange(width, dtype=np.int32), (height, width))
    gaps = ~np.isfinite(disparity)

    def nearest(mask, side):
        if side == "left":
            return np.maximum.accumulate(np.where(mask, column, np.int32(-1)), axis=1)
        flipped = np.where(mask, column, np.int32(width))[:, ::-1]
        return np.minimum.accumulate(flipped, axis=1)[:, ::-1]

    left, right = nearest(anchors, "left"), nearest(anchors, "right")
    framed = (left >= 0) & (right < width)
    framed &= (left > nearest(gaps, "left")) & (right < nearest(gaps, "right"))
    row = np.arange(height, dtype=np.int32)[:, None]
    left, right = np.clip(left, 0, width - 1), np.clip(right, 0, width - 1)
    d_left, d_right = disparity[row, left], disparity[row, right]
    t = (column - left).astype(np.float32) / np.maximum(right - left, 1)
    with np.errstate(invalid="ignore"):
        return framed & (np.abs(disparity - (d_left + t * (d_right - d_left))) <= tolerance_px)


def enclosed_mask(
    disparity: np.ndarray,
    anchors: np.ndarray,
    tolerance_px: float,
    where: np.ndarray | None = None,
) -> np.ndarray:
    """Valid pixels framed by anchors (textured valid pixels) along their row or column with a
    disparity that continues the anchors' (`_framed_along_rows`). `where`: only these pixels
    are judged (the rest come out False), and rows and columns without one are skipped: on a
    well-textured view that is nearly all of them."""
    judged = np.isfinite(disparity)
    if where is not None:
        judged &= where
    framed = np.zeros(disparity.shape, bool)
    rows = np.flatnonzero(judged.any(axis=1))
    if len(rows):
        framed[rows] = _framed_along_rows(disparity[rows], anchors[rows], tolerance_px)
    columns = np.flatnonzero(judged.any(axis=0))
    if len(columns):
        framed[:, columns] |= _framed_along_rows(
            np.ascontiguousarray(disparity[:, columns].T),
            np.ascontiguousarray(anchors[:, columns].T),
            tolerance_px,
        ).T
    return judged & framed


def supported_low_texture(
    disparity: np.ndarray,
    grey: np.ndarray,
    window_px: int,
    min_std_levels: float,
    anchor_erode_px: int,
    tolerance_px: float,
    min_framed_fraction: float,
    min_gap_px: int,
) -> np.ndarray:
    """Pixels to keep. Low-texture pixels (their window's grey-level std at most
    min_std_levels) are kept when framed (`enclosed_mask`) inside a low-texture region
    (4-connected, valid pixels) of which at least min_framed_fraction is framed. Next to the
    other low-texture pixels (unsupported regions, and those without a disparity) a band of
    half a window goes too: that is where SGBM fattens the object over the background. Anchors
    are textured pixels eroded by anchor_erode_px."""
    own = texture_mask(grey, window_px, min_std_levels, erode=False)
    low = ~own
    valid = np.isfinite(disparity)
    kernel = np.ones((anchor_erode_px, anchor_erode_px), np.uint8)
    anchors = cv2.erode(own.astype(np.uint8), kernel).astype(bool) & valid
    framed = enclosed_mask(disparity, anchors, tolerance_px, where=low)
    count, labels = cv2.connectedComponents((low & valid).astype(np.uint8), connectivity=4)
    size = np.bincount(labels.ravel(), minlength=count)
    framed_size = np.bincount(labels.ravel(), weights=(framed & low).ravel(), minlength=count)
    supported = framed_size >= min_framed_fraction * np.maximum(size, 1)
    supported[0] = False  # label 0: pixels outside every valid low-texture region
    in_supported = supported[labels]
    # Low-texture pixels without a disparity count when they form a gap of min_gap_px or more
    # (the background SGBM left empty); a few scattered holes in a smooth surface do not.
    count, gap_labels = cv2.connectedComponents((low & ~valid).astype(np.uint8), connectivity=8)
    gap_size = np.bincount(gap_labels.ravel(), minlength=count)
    gap_size[0] = 0
    gaps = gap_size[gap_labels] >= min_gap_px
    unsupported = (low & valid & ~in_supported) | gaps
    band = cv2.dilate(unsupported.astype(np.uint8), np.ones((window_px, window_px), np.uint8))
    return ~band.astype(bool) & ~(low & ~(framed & in_supported))


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

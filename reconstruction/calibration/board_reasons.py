"""Why a board was not found in an image (no contrast, blurred, too small, partly outside,
another grid size, ...), and whether a folder's boards are larger than the given size: the
messages a user needs to fix the data rather than a bare "not found"."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from reconstruction.calibration.boards import (
    CLASSIC_FLAGS,
    DETECTORS,
    BoardSpec,
    Detection,
    as_gray,
    sb_corners_with_meta,
)
from reconstruction.common.errors import ScannerError


@dataclass(frozen=True)
class DetectionLimits:
    """When a board that was not found is blamed on the image rather than reported as absent.

    min_contrast_grey: spread of grey levels (2nd to 98th percentile in the 64 px tile where it is
        largest, 8-bit) below which the image is called featureless (lens cap, exposure); sensor
        noise of 2 grey levels spreads ~8, OpenCV's stereo sample images ~200.
    min_laplacian_variance: sharpness, the variance of the Laplacian (Pech-Pacheco et al. 2000,
        "Diatom autofocusing in brightfield microscopy") in the sharpest 64 px tile, in grey
        levels squared. OpenCV's stereo sample images score ~3600-4000, ~50 after a Gaussian blur
        of 2 px, ~15 of 3 px, ~7 of 4 px (their boards are still found); a render of 20 px
        squares was found down to ~4 (8 px blur) and lost at ~2.4 (10 px). Sensor noise of
        sigma grey levels adds 20 sigma^2 (the kernel's squared weights), so noisy blurred
        images pass this test and get a later reason.
    min_corner_spacing_px: corner spacing below which a board is called too small: sharp
        rendered boards were found in every view from 8 px squares on, smaller ones in some.
    """

    def __post_init__(self) -> None:
        for name in ("min_contrast_grey", "min_laplacian_variance", "min_corner_spacing_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ScannerError(f"detection limits: {name} must be >= 0, got {value}")

    min_contrast_grey: float = 20.0
    min_laplacian_variance: float = 10.0
    min_corner_spacing_px: float = 8.0


# The board may fill a small part of the image: contrast and sharpness are those of the best
# tile, not of the whole image, whose plain background would dilute the board's edges.
_TILE_PX = 64
# Enlarging images bigger than this (pixels) to look for a tiny board costs seconds.
_ENLARGE_MAX_PIXELS = 1_300_000


def _laplacian_variance(gray: np.ndarray) -> float:
    """Sharpness of a grey image: the largest variance of the Laplacian over 64 px tiles."""
    lap = cv2.Laplacian(gray.astype(np.float32), cv2.CV_32F)
    h, w = gray.shape
    tiles = (max(1, w // _TILE_PX), max(1, h // _TILE_PX))
    return float(cv2.resize(lap * lap, tiles, interpolation=cv2.INTER_AREA).max())


def _grey_spread(gray: np.ndarray) -> tuple[float, float]:
    """The 2nd and 98th percentile of the grey levels in the 64 px tile where they differ most
    (per tile, so that a small board on a plain background still counts; the percentiles ignore
    noise and hot pixels)."""
    t = min(_TILE_PX, *gray.shape)
    h, w = (gray.shape[0] // t) * t, (gray.shape[1] // t) * t
    tiles = gray[:h, :w].reshape(h // t, t, w // t, t).transpose(0, 2, 1, 3).reshape(-1, t * t)
    lo, hi = np.percentile(tiles, (2, 98), axis=1)
    k = int(np.argmax(hi - lo))
    return float(lo[k]), float(hi[k])


def _corner_spacing_px(pixels: np.ndarray) -> float:
    """Median distance from each point to its nearest neighbour (a grid's spacing)."""
    distances, _ = cKDTree(pixels).query(pixels, k=2)
    return float(np.median(distances[:, 1]))


@dataclass(frozen=True, eq=False)
class _PartialGrid:
    """The largest chessboard corner grid in an image, whatever the board's size."""

    size: tuple[int, int]  # corners across and down, in the board's orientation if it fits
    spacing_px: float
    border_px: float  # from the outermost corner to the nearest image edge


def _partial_grid(spec: BoardSpec, gray: np.ndarray) -> _PartialGrid | None:
    """SB with CALIB_CB_LARGER from a 3x3 seed returns the largest corner grid it finds, and its
    size in the meta output (one entry per corner). Grids of fewer than a third of the board's
    corners are ignored: SB finds 3x3 to 5x3 grids in plain photographs (Middlebury's stereo
    images)."""
    flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_EXHAUSTIVE
    found, corners, meta = sb_corners_with_meta(gray, (3, 3), flags)
    if not found or corners is None or meta is None or meta.size < spec.point_count / 3:
        return None
    pixels = corners.reshape(-1, 2).astype(float)
    r, c = meta.shape[:2]
    want = (spec.cols - 1, spec.rows - 1)
    size = min(((c, r), (r, c)), key=lambda s: abs(s[0] - want[0]) + abs(s[1] - want[1]))
    h, w = gray.shape
    border = float(
        min(pixels[:, 0].min(), pixels[:, 1].min(), w - pixels[:, 0].max(), h - pixels[:, 1].max())
    )
    return _PartialGrid(size, _corner_spacing_px(pixels), border)


def _too_small(spec: BoardSpec, gray: np.ndarray, min_points: int) -> float | None:
    """Corner spacing (px of this image) of a board found only in the image enlarged 2x."""
    if gray.size > _ENLARGE_MAX_PIXELS:
        return None
    big = cv2.resize(gray, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
    detection = DETECTORS[spec.kind](spec, big)
    if detection is None or len(detection) < min_points:
        return None
    return _corner_spacing_px(detection.pixels) / 2


def _why_not_found(
    spec: BoardSpec,
    gray: np.ndarray,
    detection: Detection | None,
    min_points: int,
    limits: DetectionLimits,
) -> str:
    """Why no usable board was found, most specific cause first (see detect_board_or_reason)."""
    if spec.point_count < min_points:
        return f"the board has {spec.point_count} points, fewer than the {min_points} needed"
    lo, hi = _grey_spread(gray)
    if hi - lo < limits.min_contrast_grey:
        return (
            f"no contrast (grey levels {lo:.0f} to {hi:.0f}, need a spread >= "
            f"{limits.min_contrast_grey:g}): lens covered or wrong exposure"
        )
    if detection is not None:
        return (
            f"not enough corners: found {len(detection)} of the board's {spec.point_count}, "
            f"need {min_points} (board partly outside the image or hidden?)"
        )
    want = (spec.cols - 1, spec.rows - 1)
    grid = _partial_grid(spec, gray) if spec.kind == "chessboard" else None
    found = "" if grid is None else f"found a grid of {grid.size[0]}x{grid.size[1]} corners"
    expected = f"the board has {want[0]}x{want[1]} inner corners"
    if grid is not None:
        if grid.spacing_px < limits.min_corner_spacing_px:
            return (
                f"board too small ({grid.spacing_px:.1f} px between corners, found reliably from "
                f"{limits.min_corner_spacing_px:g}): move closer or use larger squares"
            )
        if grid.size != want and grid.size[0] >= want[0] and grid.size[1] >= want[1]:
            return (
                f"{found}, {expected}: check the board kind and size (inner corners = squares - 1)"
            )
        if grid.size != want and grid.border_px < 2 * grid.spacing_px:
            return f"board partly outside the image: {found}, {expected}"
    sharpness = _laplacian_variance(gray)
    if sharpness < limits.min_laplacian_variance:
        return (
            f"blurred (variance of Laplacian {sharpness:.1f}, need >= "
            f"{limits.min_laplacian_variance:g})"
        )
    if grid is not None and grid.size != want:
        return f"not enough corners: {found}, {expected} (board partly hidden or in glare?)"
    spacing = _too_small(spec, gray, min_points)
    if spacing is not None:
        return (
            f"board too small ({spacing:.1f} px between corners, found reliably from "
            f"{limits.min_corner_spacing_px:g}): move closer or use larger squares"
        )
    if grid is not None:
        return f"{found} but could not locate its corners (uneven light or glare?)"
    return "no board pattern found"


def detect_board_or_reason(
    spec: BoardSpec,
    image: np.ndarray,
    min_points: int = 6,
    limits: DetectionLimits = DetectionLimits(),
) -> Detection | str:
    """Board points in an RGB or grey image, or a short reason why none are usable, e.g.
    "blurred (variance of Laplacian 2.4, need >= 10)". Finding the reason costs more than the
    detection (another corner search, for a tiny board one on the image enlarged 2x)."""
    gray = as_gray(image)
    detection = DETECTORS[spec.kind](spec, gray)
    if detection is not None and len(detection) >= min_points:
        return detection
    return _why_not_found(spec, gray, detection, min_points, limits)


def larger_chessboard(spec: BoardSpec, image: np.ndarray) -> tuple[int, int] | None:
    """A grid (inner corners) one corner wider or taller than the given chessboard's, if the
    image holds one: the classic detector also finds a smaller grid inside a larger board, so a
    wrong board size would pass unnoticed (and the numbering could shift between views). One
    image can show a spurious larger grid (a board printed with cut outer squares did); a
    folder where most do has a wrong board size."""
    if spec.kind != "chessboard":
        return None
    gray = as_gray(image)
    cols, rows = spec.cols - 1, spec.rows - 1
    for pattern in ((cols + 1, rows), (cols, rows + 1)):
        found, _ = cv2.findChessboardCorners(
            gray, pattern, flags=CLASSIC_FLAGS | cv2.CALIB_CB_FAST_CHECK
        )
        if found:
            return pattern
    return None

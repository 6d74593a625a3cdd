"""Calibration boards: geometry in the board frame B, detection in images, printable pattern.

Three kinds, chosen by name (`BOARD_KINDS`):
- "charuco": a chessboard whose white squares carry ArUco markers (OpenCV's CharucoBoard). Every
  corner has an id, so partly visible boards still give correct correspondences; the default.
- "chessboard": plain squares. Its orientation is unique only when the square counts differ in
  parity (a 180-degree turn of the board maps a black square onto a white one); the detector
  then numbers the corners from the black outer top-left square. On symmetric boards it numbers
  them from the grid corner nearest the image's top-left (see `_canonical_order`). Found by
  findChessboardCornersSB, else the classic findChessboardCorners (see `_CHESSBOARD_STAGES`).
- "circles_asymmetric": OpenCV's asymmetric circle grid (e.g. the Open3DV data set: 7 x 11,
  20 mm). `inverted` boards (white dots on black) are detected on the inverted image.

Frame B (OpenCV convention, the pattern lies in z = 0, the camera looks at it along +z_B):
- charuco / chessboard: origin at the outer top-left corner of the squares, x along a row of
  squares (cols), y down the columns (rows); inner corner (i, j) at ((i + 1) s, (j + 1) s, 0),
  numbered row by row (OpenCV's CharucoBoard.getChessboardCorners order).
- circles_asymmetric: origin at the first circle; circle (i, j) at ((2 i + j % 2) s / 2, j s / 2)
  with s the centre distance along a row, numbered row by row as cv2.findCirclesGrid returns them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError

BOARD_KINDS = ("charuco", "chessboard", "circles_asymmetric")


@dataclass(frozen=True)
class BoardSpec:
    """A calibration board.

    cols, rows: squares (charuco, chessboard) or circles (circle grid) across and down.
    spacing_m: square size, or centre distance along a row of the circle grid.
    marker_m: ArUco marker size (charuco only). circle_diameter_m: printed dot size (circle grid;
    detection does not need it). inverted: white pattern on black (circle grid).
    """

    kind: str = "charuco"
    cols: int = 9
    rows: int = 7
    spacing_m: float = 0.02
    marker_m: float = 0.015
    dictionary: str = "DICT_5X5_100"
    circle_diameter_m: float = 0.0
    inverted: bool = False

    def __post_init__(self) -> None:
        if self.kind not in BOARD_KINDS:
            raise ScannerError(f"board.kind: '{self.kind}' is not one of {', '.join(BOARD_KINDS)}")
        least = 3 if self.kind == "circles_asymmetric" else 2
        for name in ("cols", "rows"):
            count = getattr(self, name)
            if not least <= count <= 200:
                raise ScannerError(
                    f"board.{name}: expected {least} to 200 along a side of a {self.kind} "
                    f"board, got {count}"
                )
        if not (math.isfinite(self.spacing_m) and 0 < self.spacing_m <= 0.5):
            raise ScannerError(
                f"board.spacing_m: expected a length in metres in (0, 0.5], got {self.spacing_m}"
            )
        if not (math.isfinite(self.circle_diameter_m) and self.circle_diameter_m >= 0):
            raise ScannerError(
                "board.circle_diameter_m: expected a length in metres (0: not given), got "
                f"{self.circle_diameter_m}"
            )
        if self.kind == "charuco":
            if not 0 < self.marker_m < self.spacing_m:
                raise ScannerError(
                    f"board.marker_m: expected between 0 and the square size {self.spacing_m} m "
                    f"(charuco), got {self.marker_m}"
                )
            if not hasattr(cv2.aruco, self.dictionary):
                raise ScannerError(
                    f"board.dictionary: unknown ArUco dictionary '{self.dictionary}'"
                )

    @property
    def point_count(self) -> int:
        if self.kind == "circles_asymmetric":
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    @property
    def size_m(self) -> tuple[float, float]:
        """Width and height of the pattern area (squares, or circle centres' extent) in metres."""
        if self.kind == "circles_asymmetric":
            return ((self.cols - 0.5) * self.spacing_m, (self.rows - 1) * self.spacing_m / 2)
        return (self.cols * self.spacing_m, self.rows * self.spacing_m)

    def object_points(self) -> np.ndarray:
        """(N, 3) points p_BP in the board frame, in detection order (ids index this array)."""
        s = self.spacing_m
        if self.kind == "circles_asymmetric":
            j, i = np.mgrid[0 : self.rows, 0 : self.cols]
            x = (2 * i + j % 2) * s / 2
            y = j * s / 2
        else:
            j, i = np.mgrid[0 : self.rows - 1, 0 : self.cols - 1]
            x, y = (i + 1) * s, (j + 1) * s
        return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1).astype(float)

    @property
    def orientation_unique(self) -> bool:
        return self.kind != "chessboard" or (self.cols + self.rows) % 2 == 1


def charuco_board(spec: BoardSpec):
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    return cv2.aruco.CharucoBoard((spec.cols, spec.rows), spec.spacing_m, spec.marker_m, dictionary)


@dataclass(frozen=True, eq=False)
class Detection:
    """Board points found in one image: ids into BoardSpec.object_points(), pixels (N, 2)."""

    ids: np.ndarray
    pixels: np.ndarray

    def __post_init__(self) -> None:
        for a in (self.ids, self.pixels):
            a.setflags(write=False)

    def __len__(self) -> int:
        return len(self.ids)


def as_gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return image


def _subpixel(gray: np.ndarray, pixels: np.ndarray, window_px: int) -> np.ndarray:
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    pts = pixels.reshape(-1, 1, 2).astype(np.float32).copy()
    cv2.cornerSubPix(gray, pts, (window_px, window_px), (-1, -1), criteria)
    return pts.reshape(-1, 2).astype(float)


def _window_px(pixels: np.ndarray, cols: int) -> int:
    """Half window of cornerSubPix: a third of the smallest corner spacing, 1 to 15 px (a window
    reaching the next corner pulls the estimate towards it: on a rendered board of 4 px squares,
    which the classic detector finds, a 3 px half window merges neighbouring corners)."""
    grid = pixels.reshape(-1, cols, 2)
    d = np.linalg.norm(np.diff(grid, axis=1), axis=2).min()
    return int(max(1, min(15, d / 3)))


def _detect_charuco(spec: BoardSpec, gray: np.ndarray) -> Detection | None:
    detector = cv2.aruco.CharucoDetector(charuco_board(spec))
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) == 0:
        return None
    return Detection(ids.ravel().astype(int), corners.reshape(-1, 2).astype(float))


# Classic findChessboardCorners: the adaptive threshold and normalisation find boards under uneven
# light. FAST_CHECK is left off: on small and blurred rendered boards it rejected views that the
# full search finds, and it only saves time on images without a board.
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
# Images longer than this are also searched at this size: the classic detector misses large,
# blurred squares in multi-megapixel images that it finds shrunk (a 1920x1080 render with 130 px
# squares blurred by 10 px).
_CLASSIC_DOWNSCALED_PX = 1024


# findChessboardCornersSB samples with OpenCV's global random generator (one per thread), so
# its answer depended on every call before it: unseeded, the same image gave "no board" 4 times
# in 100 (a test failed only inside the whole suite). Seeded before each call, a detection
# depends on the image alone.
SB_SEED = 0


def sb_corners(gray: np.ndarray, pattern: tuple[int, int], flags: int) -> tuple[bool, np.ndarray]:
    """cv2.findChessboardCornersSB, the same answer for the same image every time."""
    cv2.setRNGSeed(SB_SEED)
    return cv2.findChessboardCornersSB(gray, pattern, flags=flags)


def sb_corners_with_meta(gray: np.ndarray, pattern: tuple[int, int], flags: int) -> tuple:
    """cv2.findChessboardCornersSBWithMeta, the same answer for the same image every time."""
    cv2.setRNGSeed(SB_SEED)
    return cv2.findChessboardCornersSBWithMeta(gray, pattern, flags)


def _sb_chessboard(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """findChessboardCornersSB with CALIB_CB_ACCURACY (unbiased to ~0.02 px on our renders, where
    cornerSubPix is biased by up to 0.2 px on edges aligned with pixel rows), run on a crop
    around the board found at half resolution: the accurate mode costs ~0.7 s on a full
    1280x960 image and ~0.15 s on the crop, with the same corners (checked against the truth)."""
    accurate = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    small = cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    found, coarse = sb_corners(small, pattern, cv2.CALIB_CB_EXHAUSTIVE)
    if found:
        # Half-resolution pixel centres map to 2 u + 0.5 in the full image.
        c = coarse.reshape(-1, 2) * 2 + 0.5
        spacing = float(
            np.median(np.linalg.norm(np.diff(c.reshape(pattern[1], pattern[0], 2), axis=1), axis=2))
        )
        margin = 2 * spacing + 8
        lo = np.maximum(np.floor(c.min(axis=0) - margin), 0).astype(int)
        hi = np.minimum(np.ceil(c.max(axis=0) + margin), [gray.shape[1], gray.shape[0]]).astype(int)
        crop = np.ascontiguousarray(gray[lo[1] : hi[1], lo[0] : hi[0]])
        found, corners = sb_corners(crop, pattern, accurate)
        if found:
            return corners.reshape(-1, 2).astype(float) + lo
    found, corners = sb_corners(gray, pattern, accurate)
    return corners.reshape(-1, 2).astype(float) if found else None


def _classic_chessboard(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """Classic findChessboardCorners (quads of a thresholded image), refined by cornerSubPix. It
    finds boards SB misses: all 26 of OpenCV's stereo sample images, where SB with default
    flags finds 22 and the SB stage above 25."""
    found, corners = cv2.findChessboardCorners(gray, pattern, flags=CLASSIC_FLAGS)
    if not found:
        return None
    pixels = corners.reshape(-1, 2).astype(float)
    return _subpixel(gray, pixels, _window_px(pixels, pattern[0]))


def _downscaled_classic_chessboard(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """The classic detector on the image shrunk to _CLASSIC_DOWNSCALED_PX, refined by cornerSubPix
    at full resolution; None for images that are not larger than that."""
    scale = _CLASSIC_DOWNSCALED_PX / max(gray.shape)
    if scale >= 1:
        return None
    small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    found, corners = cv2.findChessboardCorners(small, pattern, flags=CLASSIC_FLAGS)
    if not found:
        return None
    # A pixel centre c of the small image lies at (c + 0.5) / scale - 0.5 in the full one.
    pixels = (corners.reshape(-1, 2).astype(float) + 0.5) / scale - 0.5
    return _subpixel(gray, pixels, _window_px(pixels, pattern[0]))


# Most accurate first; each later stage runs only when the earlier ones found nothing.
_CHESSBOARD_STAGES: dict[str, Callable[[np.ndarray, tuple[int, int]], np.ndarray | None]] = {
    "sb_accurate": _sb_chessboard,
    "classic": _classic_chessboard,
    "classic_downscaled": _downscaled_classic_chessboard,
}


def _find_chessboard(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    for stage in _CHESSBOARD_STAGES.values():
        pixels = stage(gray, pattern)
        if pixels is not None:
            return pixels
    return None


def _dark_squares_first(spec: BoardSpec, gray: np.ndarray, pixels: np.ndarray) -> bool:
    """Do the squares that are black on the board (square (i, j) with i + j even: the outer
    top-left one is black, as in OpenCV's pattern) look darker than the white ones, with the
    corners in this order?

    Sampled 0.3 squares diagonally off every inner corner rather than at square centres: printed
    boards often cut the outer squares short (OpenCV's stereo sample images show them at about
    0.4 of a square), and a point that far from a corner stays off its blurred edges."""
    s = spec.spacing_m
    p_B = spec.object_points()[:, :2]
    H_IB, _ = cv2.findHomography(p_B, pixels)
    offsets = 0.3 * s * np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]])
    q_B = (p_B[:, None, :] + offsets[None]).reshape(-1, 2)
    black = np.floor(q_B / s).astype(int).sum(axis=1) % 2 == 0
    uv = np.rint(cv2.perspectiveTransform(q_B[None], H_IB)[0]).astype(int)
    h, w = gray.shape
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    values = np.full(len(uv), np.nan)
    values[inside] = gray[uv[inside, 1], uv[inside, 0]]
    return bool(np.nanmedian(values[black]) < np.nanmedian(values[~black]))


def _canonical_order(spec: BoardSpec, gray: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """The corners in the order of BoardSpec.object_points(), whichever end the detector began.

    A board whose colours fix its orientation is put with its black outer top-left square first.
    Otherwise (same parity of cols and rows: a 180-degree turn, and on a square board a 90-degree
    one, maps the pattern onto itself) the first corner is the grid corner nearest the image's
    top-left, by the smallest u + v: every view of a set in which the board is turned by less
    than about 90 degrees then numbers the same physical corners alike."""
    grid = pixels.reshape(spec.rows - 1, spec.cols - 1, 2)
    if spec.orientation_unique:
        ordered = grid if _dark_squares_first(spec, gray, pixels) else grid[::-1, ::-1]
        return ordered.reshape(-1, 2).copy()
    # np.rot90 turns the index grid (a proper rotation), never mirrors it.
    turns = (0, 1, 2, 3) if spec.cols == spec.rows else (0, 2)
    candidates = [np.rot90(grid, k) for k in turns]
    best = min(candidates, key=lambda g: float(g[0, 0].sum()))
    return best.reshape(-1, 2).copy()


def _detect_chessboard(spec: BoardSpec, gray: np.ndarray) -> Detection | None:
    pixels = _find_chessboard(gray, (spec.cols - 1, spec.rows - 1))
    if pixels is None:
        return None
    return Detection(np.arange(len(pixels)), _canonical_order(spec, gray, pixels))


def _detect_circles(spec: BoardSpec, gray: np.ndarray) -> Detection | None:
    image = 255 - gray if spec.inverted else gray
    found, centres = cv2.findCirclesGrid(
        image, (spec.cols, spec.rows), flags=cv2.CALIB_CB_ASYMMETRIC_GRID
    )
    if not found:
        return None
    pixels = centres.reshape(-1, 2).astype(float)
    return Detection(np.arange(len(pixels)), pixels)


DETECTORS: dict[str, Callable[[BoardSpec, np.ndarray], Detection | None]] = {
    "charuco": _detect_charuco,
    "chessboard": _detect_chessboard,
    "circles_asymmetric": _detect_circles,
}


def detect_board(spec: BoardSpec, image: np.ndarray, min_points: int = 6) -> Detection | None:
    """Board points in an RGB or grey image, or None when fewer than `min_points` are found."""
    detection = DETECTORS[spec.kind](spec, as_gray(image))
    if detection is None or len(detection) < min_points:
        return None
    return detection


@dataclass(frozen=True, eq=False)
class BoardImage:
    """A printable pattern: grey image, and where the board frame sits on it.

    Board point (x, y) in metres lies at continuous image coordinates (edges of pixels, not
    centres) origin_px + px_per_m * (x, y); the whole image is size_m = image size / px_per_m.
    """

    image: np.ndarray
    px_per_m: float
    origin_px: tuple[float, float]

    @property
    def size_m(self) -> tuple[float, float]:
        h, w = self.image.shape[:2]
        return (w / self.px_per_m, h / self.px_per_m)

    @property
    def origin_m(self) -> tuple[float, float]:
        """Where the board origin is, measured from the image's top-left corner, in metres."""
        return (self.origin_px[0] / self.px_per_m, self.origin_px[1] / self.px_per_m)


def board_image(
    spec: BoardSpec, px_per_spacing: int = 64, margin_spacings: float = 1.0
) -> BoardImage:
    """The pattern with a white quiet zone of `margin_spacings` squares (detectors need it)."""
    n = int(px_per_spacing)
    margin = int(round(margin_spacings * n))
    px_per_m = n / spec.spacing_m
    if spec.kind == "charuco":
        inner = charuco_board(spec).generateImage((spec.cols * n, spec.rows * n), marginSize=0)
        image = cv2.copyMakeBorder(
            inner, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255
        )
        return BoardImage(image, px_per_m, (float(margin), float(margin)))
    if spec.kind == "chessboard":
        j, i = np.mgrid[0 : spec.rows * n, 0 : spec.cols * n]
        inner = np.where(((i // n) + (j // n)) % 2 == 0, 0, 255).astype(np.uint8)
        image = cv2.copyMakeBorder(
            inner, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255
        )
        return BoardImage(image, px_per_m, (float(margin), float(margin)))
    # Circle grid: draw anti-aliased discs by supersampling, so centres are exact.
    w_m, h_m = spec.size_m
    width = int(math.ceil(w_m * px_per_m)) + 2 * margin
    height = int(math.ceil(h_m * px_per_m)) + 2 * margin
    diameter = spec.circle_diameter_m or 0.4 * spec.spacing_m
    ss = 8
    fg, bg = (255, 0) if spec.inverted else (0, 255)
    big = np.full((height * ss, width * ss), bg, np.uint8)
    for x, y, _ in spec.object_points():
        cx = (margin + x * px_per_m) * ss
        cy = (margin + y * px_per_m) * ss
        # cv2.circle takes pixel-centre coordinates; edge coordinate c is centre c - 0.5.
        cv2.circle(
            big,
            (int(round((cx - 0.5) * 16)), int(round((cy - 0.5) * 16))),
            int(round(diameter / 2 * px_per_m * ss * 16)),
            fg,
            -1,
            cv2.LINE_AA,
            shift=4,
        )
    image = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)
    return BoardImage(image, px_per_m, (float(margin), float(margin)))

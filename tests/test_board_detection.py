"""Chessboard detection: every board a careful user would count, a canonical corner order, and a
reason for every image where no board is found."""

import cv2
import numpy as np
import pytest

from reconstruction.calibration import boards
from reconstruction.calibration.board_reasons import DetectionLimits, detect_board_or_reason
from reconstruction.calibration.boards import (
    BoardSpec,
    Detection,
    board_image,
    detect_board,
)
from reconstruction.common.errors import ScannerError
from tests.board_views import warped_board
from tests.conftest import shared_data

OPENCV_STEREO = "real/stereo_calibration_opencv_sample"
# OpenCV's stereo sample board: 10x7 squares (9x6 inner corners); the square size is not published
# and does not matter for detection.
OPENCV_BOARD = BoardSpec("chessboard", 10, 7, 0.025)
BOARD = BoardSpec("chessboard", 10, 7, 0.02)  # orientation fixed by its colours
SYMMETRIC = BoardSpec("chessboard", 9, 7, 0.02)  # the same after a 180-degree turn
SQUARE = BoardSpec("chessboard", 8, 8, 0.02)  # the same after a 90-degree turn


def _on_canvas(image, x, y, size=(640, 480)):
    """`image` pasted with its top-left at (x, y) on a white canvas, cut by the canvas edges."""
    canvas = np.full((size[1], size[0]), 255, np.uint8)
    h, w = image.shape
    x1, y1 = min(size[0], x + w), min(size[1], y + h)
    canvas[y:y1, x:x1] = image[: y1 - y, : x1 - x]
    return canvas


# ---------------------------------------------------------------------------- real images
def test_every_image_of_opencv_stereo_sample_is_found_in_one_order():
    """OpenCV's stereo sample: SB alone finds 22 of the 26 images, the classic detector all."""
    root = shared_data(OPENCV_STEREO)
    lefts = sorted((root / "left").glob("left*.jpg"))
    assert len(lefts) == 13
    for left_path in lefts:
        right_path = root / "right" / left_path.name.replace("left", "right")
        left = detect_board(OPENCV_BOARD, cv2.imread(str(left_path), cv2.IMREAD_GRAYSCALE))
        right = detect_board_or_reason(
            OPENCV_BOARD, cv2.imread(str(right_path), cv2.IMREAD_GRAYSCALE)
        )
        assert left is not None, left_path.name
        assert isinstance(right, Detection), f"{right_path.name}: {right}"
        assert len(left) == len(right) == OPENCV_BOARD.point_count
        # Corner k is the same physical corner in both cameras: left to right, every corner
        # moves by about the same disparity (~115-175 px here, 13 px down); numbered from the
        # other end, corners would move by up to the board's diagonal (~300-400 px).
        shift = right.pixels - left.pixels
        spread_px = np.linalg.norm(shift - np.median(shift, axis=0), axis=1).max()
        assert spread_px < 80, left_path.name


# ---------------------------------------------------------------------------- stages
@pytest.mark.parametrize("spec", [BOARD, SYMMETRIC, SQUARE], ids=["10x7", "9x7", "8x8"])
def test_every_stage_finds_a_render_accurately_in_the_same_order(spec, monkeypatch):
    """SB (accuracy mode) is the most precise; the classic detector refined by cornerSubPix is
    biased by ~0.1 px on rendered edges, and the same from a downscaled search."""
    image, expected = warped_board(spec)
    pattern = (spec.cols - 1, spec.rows - 1)
    # The render is small; make the downscaled stage run at about half its size.
    monkeypatch.setattr(boards, "_CLASSIC_DOWNSCALED_PX", max(image.shape) // 2)
    tolerance_px = {"sb_accurate": 0.05, "classic": 0.15, "classic_downscaled": 0.15}
    for name, stage in boards._CHESSBOARD_STAGES.items():
        pixels = stage(image, pattern)
        assert pixels is not None, name
        ordered = boards._canonical_order(spec, image, pixels)
        err = np.linalg.norm(ordered - expected, axis=1)
        assert np.median(err) < tolerance_px[name], name
        assert err.max() < 2 * tolerance_px[name], name


def test_the_classic_stage_finds_a_board_sb_misses():
    """A big board blurred by 10 px in a 1920x1080 image: the classic search at full size
    misses it, the downscaled one finds it, refined at full resolution."""
    rng = np.random.default_rng(0)
    pattern = board_image(BOARD, px_per_spacing=100)
    h, w = pattern.image.shape
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = (src - [w / 2, h / 2]) * 1.3 + [960, 540] + rng.normal(0, 60, (4, 2))
    H = cv2.getPerspectiveTransform(src, np.float32(dst))
    image = cv2.warpPerspective(pattern.image, H, (1920, 1080), borderValue=200)
    image = cv2.GaussianBlur(image, (0, 0), 10)
    size = (BOARD.cols - 1, BOARD.rows - 1)
    assert boards._classic_chessboard(image, size) is None
    pixels = boards._downscaled_classic_chessboard(image, size)
    assert pixels is not None
    edges = pattern.origin_px + BOARD.object_points()[:, :2] * pattern.px_per_m
    expected = cv2.perspectiveTransform(edges[None].astype(np.float64), H)[0] - 0.5
    err = np.linalg.norm(boards._canonical_order(BOARD, image, pixels) - expected, axis=1)
    assert np.median(err) < 0.5  # a 10 px blur: corners within half a pixel


# ---------------------------------------------------------------------------- corner order
def test_a_symmetric_board_is_numbered_from_the_corner_nearest_the_image_top_left():
    pattern = board_image(SYMMETRIC, px_per_spacing=40).image
    h, w = pattern.shape
    upright = detect_board(SYMMETRIC, pattern)
    turned = detect_board(SYMMETRIC, cv2.rotate(pattern, cv2.ROTATE_180))
    for detection in (upright, turned):
        sums = detection.pixels.sum(axis=1)
        assert sums[0] == sums.min()
    # Pixel (u, v) of the turned image is (w - 1 - u, h - 1 - v) of the upright one: the turned
    # board's first corner is the upright board's last.
    mapped = np.array([w - 1, h - 1]) - turned.pixels
    assert np.abs(mapped[::-1] - upright.pixels).max() < 0.2
    reversed_order = boards._canonical_order(SYMMETRIC, pattern, upright.pixels[::-1])
    np.testing.assert_array_equal(reversed_order, upright.pixels)


def test_a_square_board_turned_by_90_degrees_is_numbered_from_the_top_left():
    pattern = board_image(SQUARE, px_per_spacing=40).image
    upright = detect_board(SQUARE, pattern)
    for turn in (cv2.ROTATE_90_CLOCKWISE, cv2.ROTATE_180, cv2.ROTATE_90_COUNTERCLOCKWISE):
        turned = detect_board(SQUARE, cv2.rotate(pattern, turn))
        assert np.abs(turned.pixels - upright.pixels).max() < 0.2


def test_orientation_by_colour_holds_on_a_board_with_cut_outer_squares():
    """Printed boards often cut the outer squares short (OpenCV's sample board shows them at
    ~0.4 of a square): the black top-left square is still found first, upside down too."""
    n, margin = 40, 40
    pattern = board_image(BOARD, px_per_spacing=n, margin_spacings=1).image.copy()
    h, w = pattern.shape
    keep = int(0.4 * n)
    # Whiten the outer ring of squares beyond `keep` px from the first inner corner line.
    pattern[:, : margin + n - keep] = 255
    pattern[:, w - margin - n + keep :] = 255
    pattern[: margin + n - keep, :] = 255
    pattern[h - margin - n + keep :, :] = 255
    upright = detect_board(BOARD, pattern)
    turned = detect_board(BOARD, cv2.rotate(pattern, cv2.ROTATE_180))
    first = np.array([margin + n - 0.5, margin + n - 0.5])  # inner corner (0, 0), pixel centres
    # Numbered from the wrong end, corners would be hundreds of px off; within a pixel, the
    # corners next to the cut squares differ by up to ~0.4 px between the two views.
    assert np.abs(upright.pixels[0] - first).max() < 1
    mapped = np.array([w - 1, h - 1]) - turned.pixels
    assert np.abs(mapped - upright.pixels).max() < 1
    # Whichever end a detector starts from, the order comes out the same.
    for pixels in (upright.pixels, upright.pixels[::-1]):
        np.testing.assert_array_equal(
            boards._canonical_order(BOARD, pattern, pixels), upright.pixels
        )


# ---------------------------------------------------------------------------- reasons
def test_a_blurred_board_is_reported_as_blurred():
    image = _on_canvas(board_image(BOARD, px_per_spacing=20).image, 100, 100)
    assert isinstance(detect_board_or_reason(BOARD, image), Detection)
    blurred = cv2.GaussianBlur(image, (0, 0), 10)  # 10 px: beyond what the detectors survive
    reason = detect_board_or_reason(BOARD, blurred)
    assert isinstance(reason, str) and reason.startswith("blurred (variance of Laplacian")
    assert detect_board(BOARD, blurred) is None


@pytest.mark.parametrize(
    "x, y, found", [(260, 40, "8x6"), (80, 220, "9x5")], ids=["right edge", "bottom edge"]
)
def test_a_board_cut_by_the_image_border_says_what_was_found(x, y, found):
    image = _on_canvas(board_image(BOARD, px_per_spacing=40).image, x, y)
    reason = detect_board_or_reason(BOARD, image)
    assert reason == (
        f"board partly outside the image: found a grid of {found} corners, the board has 9x6 "
        "inner corners"
    )


def test_a_board_of_another_size_is_named():
    image = _on_canvas(board_image(BOARD, px_per_spacing=20).image, 100, 100)
    reason = detect_board_or_reason(SYMMETRIC, image)
    assert "found a grid of 9x6 corners, the board has 8x6 inner corners" in reason
    assert "check the board kind and size" in reason


def test_a_tiny_board_is_reported_as_too_small():
    rng = np.random.default_rng(0)
    big = board_image(BOARD, px_per_spacing=40).image
    tiny = cv2.resize(big, None, fx=3 / 40, fy=3 / 40, interpolation=cv2.INTER_AREA)
    image = cv2.GaussianBlur(_on_canvas(tiny, 300, 200).astype(np.float32), (0, 0), 1.0)
    image = np.clip(0.8 * image + 20 + rng.normal(0, 2, image.shape), 0, 255).astype(np.uint8)
    reason = detect_board_or_reason(BOARD, image)
    assert reason.startswith("board too small (3.0 px between corners")


def test_a_covered_lens_and_an_empty_scene_have_their_own_reasons():
    dark = np.full((480, 640), 3, np.uint8)
    assert detect_board_or_reason(BOARD, dark).startswith("no contrast (grey levels 3 to 3")
    rng = np.random.default_rng(0)
    scene = np.full((480, 640), 128, np.uint8)
    for _ in range(40):
        centre = tuple(int(c) for c in rng.integers(0, [640, 480]))
        cv2.circle(scene, centre, int(rng.integers(5, 60)), int(rng.integers(0, 255)), -1)
    for spec in (BOARD, BoardSpec("charuco", 9, 7, 0.02, 0.015)):
        assert detect_board_or_reason(spec, scene) == "no board pattern found"


def test_too_few_charuco_corners_are_counted():
    spec = BoardSpec("charuco", 9, 7, 0.02, 0.015)
    pattern = board_image(spec, px_per_spacing=40).image
    corner = np.ascontiguousarray(pattern[:160, :200])  # about 2x2 squares of corners
    detection = detect_board(spec, corner, min_points=1)
    assert detection is not None and len(detection) < 20
    reason = detect_board_or_reason(spec, corner, min_points=20)
    assert reason.startswith(f"not enough corners: found {len(detection)} of the board's 48")


def test_detection_limits_decide_what_is_blamed():
    blurred = cv2.GaussianBlur(
        _on_canvas(board_image(BOARD, px_per_spacing=20).image, 100, 100), (0, 0), 10
    )
    lenient = DetectionLimits(min_laplacian_variance=0.0)
    assert not detect_board_or_reason(BOARD, blurred, limits=lenient).startswith("blurred")
    with pytest.raises(ScannerError, match="min_corner_spacing_px must be >= 0"):
        DetectionLimits(min_corner_spacing_px=-1.0)

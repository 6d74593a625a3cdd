"""Disparity of a rectified stereo pair by OpenCV's StereoSGBM, with the rejection filters.

Disparity is left-referenced and in pixels: a left pixel (u, v) of the rectified pair matches the
right pixel (u - d, v). Depth in the rectified left frame is Z = f b / d, so a depth window
[z_min, z_max] fixes the SGBM search range (`disparity_window`), never a constant.
"""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.filters import (
    jump_mask,
    left_right_mask,
    supported_low_texture,
    texture_mask,
)
from reconstruction.stereo.params import (
    ONE_WAY_MODES,
    SGBM_MODES,
    SGBM_SCALE,
    UPWARD_PASS_AGREEMENT_PX,
    StereoParams,
    stereo_params,
)


def _check_image(image: np.ndarray, name: str) -> None:
    if not isinstance(image, np.ndarray):
        raise ScannerError(f"{name} image: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ScannerError(f"{name} image: expected 8-bit pixels (uint8), got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))):
        channels = image.shape[2] if image.ndim == 3 else f"{image.ndim} dimensions"
        raise ScannerError(
            f"{name} image: expected grey (H, W) or RGB (H, W, 3), got shape {image.shape} "
            f"({channels} channels)"
        )
    if min(image.shape[:2]) < 1:
        raise ScannerError(f"{name} image: empty ({image.shape})")


def grey_image(image: np.ndarray, name: str) -> np.ndarray:
    """RGB (the simulator's and our capture files' channel order) or grey -> grey."""
    _check_image(image, name)
    if image.ndim == 2:
        return image
    if image.shape[2] == 1:
        return image[..., 0]
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def check_pair(left: np.ndarray, right: np.ndarray) -> None:
    """Both images uint8 grey or RGB, of the same size; a ScannerError naming the problem."""
    _check_image(left, "left")
    _check_image(right, "right")
    if left.shape[:2] != right.shape[:2]:
        raise ScannerError(
            f"stereo pair: left image is {left.shape[1]}x{left.shape[0]} but right image is "
            f"{right.shape[1]}x{right.shape[0]}"
        )


# Added to a raw SGBM disparity (sixteenths of a pixel) by its residue k = raw mod 16: the centre
# of the parabola offsets that OpenCV reports as that residue (see decoded_sixteenths). Residue 0
# also collects the offsets in (-1.5, -0.5), so its centre is -0.5; residue 8 only comes from
# [7.5, 8], residue 9 from (-8, -7.5]; residues 10..15 are one sixteenth too high.
_SUBPIXEL_CORRECTION_SIXTEENTHS = np.array(
    [-0.5, 0, 0, 0, 0, 0, 0, 0, -0.25, -0.75, -1, -1, -1, -1, -1, -1], np.float32
)


def decoded_sixteenths(raw: np.ndarray) -> np.ndarray:
    """Raw SGBM disparities (int16, sixteenths of a pixel) -> float32 sixteenths without the
    rounding bias of OpenCV's sub-pixel step.

    OpenCV rounds the parabola's offset delta (in sixteenths) as the C integer quotient of
    delta + 1/2, which truncates towards zero: for delta < -1/2 the result is one sixteenth too
    high, a mean bias of about +0.03 px. Each residue is mapped to the centre of the offsets that
    produce it; np.mod keeps the residue in 0..15 for negative disparities too.
    """
    raw = np.asarray(raw)
    return raw.astype(np.float32) + _SUBPIXEL_CORRECTION_SIXTEENTHS[np.mod(raw, SGBM_SCALE)]


def equiangular_px(parabolic_px: np.ndarray) -> np.ndarray:
    """Disparities (px) whose sub-pixel offsets came from a parabola fit -> the offsets of the
    equiangular (V-shaped) fit to the same three costs.

    Costs that rise linearly on either side of a true offset t in [-1/2, 1/2] give the parabola
    p = t / (2 (1 - |t|)), pulled towards the whole pixel; inverted, t = 2 p / (1 + 2 |p|).
    Whole and half pixels stay; the order of disparities is kept.
    """
    whole = np.round(parabolic_px)
    p = parabolic_px - whole
    return (whole + 2 * p / (1 + 2 * np.abs(p))).astype(np.float32)


def _sgbm(left, right, min_disparity, num_disparities, params: StereoParams) -> np.ndarray:
    """SGBM in pixels (sub-pixel rounding bias removed: decoded_sixteenths; offsets re-read by
    `params.subpixel_fit`), NaN where SGBM found nothing.

    Left columns below min_disparity can only match outside the right image and right columns
    beyond width - min_disparity only left pixels outside the left image, so both are cropped
    before matching (about 20 % less work at the working distance); the result is the same.
    """
    height, width = left.shape
    shift = min(max(min_disparity, 0), width - 1)
    channels = 1
    p1, p2 = params.penalties(channels)
    matcher = cv2.StereoSGBM_create(
        minDisparity=min_disparity - shift,
        numDisparities=num_disparities,
        blockSize=params.block_size_px,
        P1=p1,
        P2=p2,
        disp12MaxDiff=params.disp12_max_diff_px,
        uniquenessRatio=params.uniqueness_ratio_percent,
        speckleWindowSize=params.speckle_window_px,
        speckleRange=params.speckle_range_px,
        mode=SGBM_MODES[params.mode],
    )
    raw = matcher.compute(left[:, shift:], right[:, : width - shift])
    disparity = np.full((height, width), np.nan, np.float32)
    found = raw >= (min_disparity - shift) * SGBM_SCALE
    decoded = decoded_sixteenths(raw[found]) / SGBM_SCALE + shift
    if params.subpixel_fit == "equiangular":
        decoded = equiangular_px(decoded)
    disparity[:, shift:][found] = decoded
    return disparity


def with_upward_pass(downward: np.ndarray, upward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(disparity, agreed) from a pass whose vertical cost paths come from above and one whose
    paths come from below (NaN = no match). The disparity is their mean where both agree within
    UPWARD_PASS_AGREEMENT_PX, else the downward pass's value, else the upward one's; `agreed`
    marks the pixels of the mean.

    Where the disparity changes down the image, a one-way pass lags about a row behind it
    (-0.04 px at 0.04 px per row on a textured plane, -0.2 px at 0.15 px per row on simulated
    views) and the other pass lags by as much the other way. Where the passes disagree (by more
    than 1 px) or only one matched, 40-75 % of the pixels are more than 1 px off on simulated
    views (Middlebury Tsukuba 44-60 %, Venus 11-30 %), against 2-5 % (1.4-3.4 %) where they
    agree.
    """
    both = np.isfinite(downward) & np.isfinite(upward)
    with np.errstate(invalid="ignore"):
        agreed = both & (np.abs(downward - upward) <= UPWARD_PASS_AGREEMENT_PX)
    merged = np.where(np.isfinite(downward), downward, upward)
    merged[agreed] = 0.5 * (downward[agreed] + upward[agreed])
    return merged.astype(np.float32), agreed


def _matched(
    left, right, min_disparity, num_disparities, params: StereoParams
) -> tuple[np.ndarray, np.ndarray | None]:
    """_sgbm, with the upside-down pass for the one-way modes (`with_upward_pass`): the
    disparity and the pixels where both passes agreed (None: a single pass)."""
    downward = _sgbm(left, right, min_disparity, num_disparities, params)
    if not params.upward_pass or params.mode not in ONE_WAY_MODES:
        return downward, None
    upward = _sgbm(left[::-1].copy(), right[::-1].copy(), min_disparity, num_disparities, params)
    return with_upward_pass(downward, upward[::-1])


def compute_disparity(
    left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int, **params
) -> np.ndarray:
    """Left-referenced disparity (float32 pixels, NaN = invalid) of a RECTIFIED pair.

    left, right: uint8 grey (H, W) or RGB (H, W, 3). params: StereoParams fields by name.
    """
    return disparity_image(left, right, min_disparity, num_disparities, stereo_params(**params))


def disparity_image(
    left: np.ndarray,
    right: np.ndarray,
    min_disparity: int,
    num_disparities: int,
    params: StereoParams,
) -> np.ndarray:
    """compute_disparity with a StereoParams record."""
    check_pair(left, right)
    if not (isinstance(num_disparities, int | np.integer) and num_disparities > 0):
        raise ScannerError(f"num_disparities: must be a positive integer, got {num_disparities}")
    if num_disparities % SGBM_SCALE:
        raise ScannerError(f"num_disparities: must be a multiple of 16, got {num_disparities}")
    width = left.shape[1]
    # OpenCV needs a full search plus half a block inside the (cropped) image, else it fails.
    if width - max(int(min_disparity), 0) < num_disparities + params.block_size_px:
        raise ScannerError(
            f"disparity search {min_disparity}..{min_disparity + num_disparities} px does not fit "
            f"a {width} px wide image: no pixel could be matched (use a farther depth window)"
        )
    grey_left, grey_right = grey_image(left, "left"), grey_image(right, "right")
    disparity, agreed = _matched(grey_left, grey_right, int(min_disparity), num_disparities, params)
    keep = np.isfinite(disparity)
    if params.lr_check_max_diff_px is not None:
        # Right-referenced disparity: mirror both images and swap them.
        mirrored, _ = _matched(
            grey_right[:, ::-1].copy(),
            grey_left[:, ::-1].copy(),
            int(min_disparity),
            num_disparities,
            params,
        )
        keep &= left_right_mask(disparity, mirrored[:, ::-1], params.lr_check_max_diff_px)
    disparity[~keep] = np.nan
    if params.texture_min_std_levels > 0 and params.low_texture == "reject":
        disparity[
            ~texture_mask(grey_left, params.texture_window_px, params.texture_min_std_levels)
        ] = np.nan
    elif params.texture_min_std_levels > 0:
        disparity[
            ~supported_low_texture(
                disparity,
                grey_left,
                params.texture_window_px,
                params.texture_min_std_levels,
                params.support_anchor_erode_px,
                params.support_tolerance_px,
                params.support_min_fraction,
                params.support_min_gap_px,
            )
        ] = np.nan
    if params.max_jump_px > 0:
        disparity[~jump_mask(disparity, params.jump_window_px, params.max_jump_px)] = np.nan
    if agreed is not None:
        # Only now: the low-texture filter judges support on the passes' full coverage, so
        # that these holes do not grow into its background bands.
        disparity[~agreed] = np.nan
    return disparity

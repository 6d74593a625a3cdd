"""Settings of the stereo matcher and the search window derived from a depth window.

Defaults chosen by measurement on the simulator (vase, 0.2 m, at 0.5 m, 4 views, 1280x960,
depth window 0.33-0.67 m = 240 disparities, 2-core machine; median / p90 |depth error|, share of
object pixels valid, seconds per pair including rectification and reprojection):
    mode 3WAY  0.22 mm / 1.05 mm, 0.92 valid, 0.23 s
    mode SGBM  0.24 mm / 0.97 mm, 0.89 valid, 0.42 s
    mode HH4   0.17 mm / 0.74 mm, 0.90 valid, 0.52 s
    mode HH    0.15 mm / 0.61 mm, 0.88 valid, 0.95 s
3WAY is the only mode inside the 0.4 s budget and meets the accuracy targets (median 0.5 mm,
p90 2 mm). Its default second, upward pass (`upward_pass`) cancels its vertical lag for 1.5x
the time a pair (0.57 -> 0.87 s on a slower shared machine, which puts the 0.23 s above at
about 0.35 s): median / p90 0.21 / 0.93 -> 0.15 / 0.59 mm, valid 0.91 -> 0.89. Block 3 keeps
2 % more object pixels than block 5 on slanted surfaces at the same accuracy; a full second
left-right pass costs 0.12 s and 4 % of the object pixels for 0.01 mm.
Half OpenCV's P1 (4 cn bs^2) measured 0.02 mm better and 1 % more coverage; the default stays
OpenCV's advice, p1 is a parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2

from reconstruction.common.checks import check_fields, integer, non_negative, require_choice
from reconstruction.common.errors import ScannerError

SGBM_MODES = {
    "SGBM": cv2.STEREO_SGBM_MODE_SGBM,
    "HH": cv2.STEREO_SGBM_MODE_HH,
    "HH4": cv2.STEREO_SGBM_MODE_HH4,
    "3WAY": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
}
# Modes whose vertical cost paths come from the rows above only (`StereoParams.upward_pass`).
ONE_WAY_MODES = ("3WAY", "SGBM")
LOW_TEXTURE_POLICIES = ("supported", "reject")
SUBPIXEL_FITS = ("equiangular", "parabola")
# Where the two passes (`StereoParams.upward_pass`) differ by more than this, the pixel is
# dropped. 1 px dropped more of the grazing surfaces than it saved (24-view spot: observed
# Chamfer 0.201 mm, completeness 0.972; 2 px: 0.193 mm, 0.978; one pass 0.178 mm, 0.985).
UPWARD_PASS_AGREEMENT_PX = 2.0
# OpenCV returns fixed-point disparities with 4 fractional bits.
SGBM_SCALE = 16


@dataclass(frozen=True)
class StereoParams:
    """SGBM settings and the filters applied to its output. Disparities in pixels.

    Matching runs on grey images (cn = 1 below). Every filter marks pixels invalid (NaN); none
    changes a disparity value.
    """

    # Odd side of the matched block (OpenCV advises 3..11).
    block_size_px: int = 3
    # SGBM penalties (cost units) for a disparity change of 1 px and of more than 1 px between
    # neighbours; None = OpenCV's advice 8 cn bs^2 and 32 cn bs^2.
    p1: float | None = None
    p2: float | None = None
    # The best matching cost must beat the second best by this margin.
    uniqueness_ratio_percent: int = integer(10, minimum=0)
    # Connected regions smaller than this many pixels whose disparity varies by at most
    # speckle_range_px are removed (0 = off).
    speckle_window_px: int = integer(100, minimum=0)
    speckle_range_px: int = integer(2, minimum=0)
    # OpenCV's internal left-right check from the same cost volume (cheap; OpenCV 4 runs it with
    # at least 1 px even when asked to switch it off, measured; so 0 is refused).
    disp12_max_diff_px: int = integer(1)
    # "SGBM" (5 directions), "HH" (8 directions, full-image memory), "HH4" or "3WAY" (fastest);
    # 3WAY by measurement (module docstring). 3WAY and SGBM aggregate their cost paths from the
    # rows above only: where the disparity changes down the image their match lags by about a
    # row (-0.04 px at 0.04 px per row, tests/test_sgbm_subpixel.py), which views from all
    # around do not average out (the fandisk's model sat 0.14 mm inside the part). upward_pass
    # cancels it; HH4 does too, at 1.4x the time a pair of 3WAY with it (1.20 / 0.87 s).
    mode: str = "3WAY"
    # 3WAY and SGBM: also match the pair turned upside down, whose vertical paths come from
    # below and lag the other way; keep the mean of the two where they agree within
    # UPWARD_PASS_AGREEMENT_PX and drop the other pixels, of which about half are wrong
    # (`matching.with_upward_pass`). Measured, 24-view scans, observed Chamfer / p90 in mm:
    # bunny 0.159 / 0.313 -> 0.149 / 0.261, fandisk 0.217 / 0.370 -> 0.169 / 0.263, teapot
    # 0.174 / 0.367 -> 0.176 / 0.292, spot 0.178 / 0.283 -> 0.193 / 0.218 (it loses some
    # grazing surface: completeness 0.985 -> 0.978). Middlebury Tsukuba: bad pixels
    # 4.76 -> 3.87 %, density 0.973 -> 0.959; Venus 1.47 -> 1.51 %, 0.911 -> 0.902. Twice the
    # matching time (HH4, the other way to cancel the lag: 4.2x).
    upward_pass: bool = True
    # SGBM's sub-pixel step fits a parabola to the three costs around the best whole
    # disparity; its costs rise about linearly on either side of the minimum, so the parabola
    # pulls offsets towards whole pixels (pixel locking: +-0.07 px on a textured slanted plane).
    # "equiangular" re-reads each offset as the V-shaped fit's (`matching.equiangular_px`);
    # "parabola" keeps OpenCV's. Measured: slanted-plane error 0.108 -> 0.081 px (mean abs),
    # simulated views 0.205 -> 0.198 px, Middlebury Venus 0.178 -> 0.160 px (bad pixels
    # 1.38 -> 1.47 %; Tsukuba's whole-pixel truth cannot show a sub-pixel gain).
    subpixel_fit: str = "equiangular"
    # If set, a second SGBM pass with the right image as reference; left pixels whose match does
    # not point back within this many pixels are rejected (doubles the matching time).
    lr_check_max_diff_px: float | None = None
    # Low texture: pixels whose grey-level std over the window is at most
    # texture_min_std_levels (0 = no texture filter; 4 levels is twice the simulated sensor
    # noise). low_texture "supported" (`stereo.filters.supported_low_texture`): such pixels stay
    # when their disparity continues that of textured pixels on both sides (within
    # support_tolerance_px, anchors eroded by support_anchor_erode_px) in a region mostly so
    # framed (support_min_fraction); next to unsupported regions and to gaps of
    # support_min_gap_px pixels without disparity, a band of half a window goes (SGBM's
    # fattening over the background). Smooth real surfaces stay, the skirt over a featureless
    # background goes. "reject": every pixel with a low-texture neighbour goes (the simulator
    # is fine with it; smooth real surfaces go too: Middlebury density 0.40-0.58).
    # Measured with these defaults: Middlebury Tsukuba / Venus density 0.974 / 0.911, bad
    # pixels (> 1 px) 4.76 / 1.38 % with the sub-pixel decoding (4.63 / 1.39 % before it;
    # plain SGBM 0.98 / 0.96, 4.65 / 1.52 %); simulated background false-valid 0.13 % (vase)
    # / 0.16 % (bracket), 3.9-4.0 % without the filter;
    # the 24-view bunny's observed-surface Chamfer 0.234 mm ("reject": 0.237 mm).
    texture_window_px: int = 9
    texture_min_std_levels: float = non_negative(4.0)
    low_texture: str = "supported"
    support_tolerance_px: float = non_negative(2.0)
    support_min_fraction: float = 0.5
    support_anchor_erode_px: int = 3
    # Low-texture pixels without a disparity in a connected gap of this many pixels or more
    # are background: a band of half a texture window next to them goes (SGBM's fattening).
    support_min_gap_px: int = integer(20, minimum=0)
    # Pixels whose window holds valid disparities further apart than max_jump_px are rejected
    # (0 = off): the fattened band at depth steps. 8 px is a 13 mm step at 0.5 m; a 3 px window
    # matches the 3 px block, which blurs a step over about one pixel on each side.
    jump_window_px: int = 3
    max_jump_px: float = non_negative(8.0)
    # Clouds keep every n-th row and column (the disparity image is always dense).
    subsample_step_px: int = integer(1)

    def __post_init__(self) -> None:
        require_choice("stereo", "mode", self.mode, SGBM_MODES)
        require_choice("stereo", "subpixel_fit", self.subpixel_fit, SUBPIXEL_FITS)
        require_choice("stereo", "low_texture", self.low_texture, LOW_TEXTURE_POLICIES)
        if not isinstance(self.upward_pass, bool):
            raise ScannerError(
                f"stereo.upward_pass: must be true or false, got {self.upward_pass!r}"
            )
        for name in (
            "block_size_px",
            "texture_window_px",
            "jump_window_px",
            "support_anchor_erode_px",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1 and value % 2 == 1):
                raise ScannerError(f"stereo.{name}: must be an odd positive integer, got {value}")
        check_fields("stereo", self)
        if not 0.0 <= self.support_min_fraction <= 1.0:
            raise ScannerError(
                f"stereo.support_min_fraction: must be within 0..1, got {self.support_min_fraction}"
            )
        if self.lr_check_max_diff_px is not None and not self.lr_check_max_diff_px > 0:
            raise ScannerError(
                f"stereo.lr_check_max_diff_px: must be positive or None, got "
                f"{self.lr_check_max_diff_px}"
            )
        p1, p2 = self.penalties(1)
        if not 0 < p1 < p2:
            raise ScannerError(f"stereo.p1, stereo.p2: need 0 < p1 < p2, got {p1}, {p2}")

    def penalties(self, channels: int) -> tuple[int, int]:
        area = channels * self.block_size_px**2
        p1 = 8 * area if self.p1 is None else self.p1
        p2 = 32 * area if self.p2 is None else self.p2
        return int(round(p1)), int(round(p2))


def stereo_params(**params) -> StereoParams:
    """StereoParams from keyword arguments; an unknown name is a user error listing valid ones."""
    valid = {f.name for f in fields(StereoParams)}
    unknown = sorted(set(params) - valid)
    if unknown:
        raise ScannerError(f"stereo: unknown parameter(s) {unknown}; valid: {sorted(valid)}")
    return StereoParams(**params)


def disparity_window(
    z_min_m: float, z_max_m: float, focal_px: float, baseline_m: float, margin_px: float = 2.0
) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering depths [z_min_m, z_max_m] (rectified frame).

    margin_px widens the range on both sides: SGBM's sub-pixel fit needs a neighbour on each
    side of the best disparity. num_disparities is rounded up to OpenCV's multiple of 16.
    """
    if not (0 < z_min_m < z_max_m and math.isfinite(z_max_m)):
        raise ScannerError(f"depth window: need 0 < z_min < z_max, got [{z_min_m}, {z_max_m}] m")
    if not (focal_px > 0 and baseline_m > 0):
        raise ScannerError(f"focal length {focal_px} px and baseline {baseline_m} m must be > 0")
    d_low = focal_px * baseline_m / z_max_m - margin_px
    d_high = focal_px * baseline_m / z_min_m + margin_px
    min_disparity = max(int(math.floor(d_low)), 0)
    span = d_high - min_disparity
    return min_disparity, int(math.ceil(span / SGBM_SCALE) * SGBM_SCALE)


def object_depth_window(distance_m: float, radius_m: float) -> tuple[float, float]:
    """(z_min_m, z_max_m) of an object within radius_m of a point distance_m ahead of the camera.

    The bounding sphere is conservative: it holds the object from every viewing direction, at the
    price of a wider search (0.5 m +- 0.17 m -> 240 disparities at f 1243 px, b 0.12 m).
    """
    if not (0 < radius_m < distance_m and math.isfinite(distance_m)):
        raise ScannerError(
            f"depth window: need 0 < radius < distance, got radius {radius_m} m, "
            f"distance {distance_m} m"
        )
    return distance_m - radius_m, distance_m + radius_m

"""OpenCV SGBM's sub-pixel rounding bias and its decoding (`matching.decoded_sixteenths`).

OpenCV rounds the parabola's offset with a C integer division that truncates towards zero, so
every offset below -1/2 sixteenth comes out one sixteenth too high. The decoding maps each
reported residue to the centre of the offsets that produce it. The parabola itself pulls offsets
towards whole pixels when costs rise linearly (pixel locking); the default equiangular reading
(`matching.equiangular_px`) inverts that.
"""

import functools

import cv2
import numpy as np
import pytest

import reconstruction.stereo.matching as matching
from reconstruction.stereo.matching import (
    compute_disparity,
    decoded_sixteenths,
    equiangular_px,
    with_upward_pass,
)

WIDTH_PX, HEIGHT_PX = 640, 480
# Columns left of the largest disparity have no match; a margin on the other sides keeps
# SGBM's border handling out of the statistics.
BORDER_PX = 48


def test_decoding_of_each_residue_positive():
    raw = np.arange(48, 64, dtype=np.int16)  # 3 px and residues 0..15
    expected = [47.5, 49, 50, 51, 52, 53, 54, 55, 55.75, 56.25, 57, 58, 59, 60, 61, 62]
    decoded = decoded_sixteenths(raw)
    assert decoded.dtype == np.float32
    np.testing.assert_array_equal(decoded, np.array(expected, np.float32))


def test_decoding_of_each_residue_negative():
    # -2 px and residues 0..15 (floor-mod: -32 + k has residue k).
    raw = np.arange(-32, -16, dtype=np.int16)
    expected = [-32.5, -31, -30, -29, -28, -27, -26, -25, -24.25, -23.75, -23, -22, -21, -20,
                -19, -18]  # fmt: skip
    np.testing.assert_array_equal(decoded_sixteenths(raw), np.array(expected, np.float32))


@pytest.mark.parametrize(
    ("raw", "expected"),
    [
        # -7 = 0 px - 7/16: the truncated quotient is -7 for an offset in (-8, -7.5] sixteenths
        # from 0 px, whose centre is -7.75 (residue 9).
        (-7, -7.75),
        # -1: an offset in (-2.5, -1.5] from 0 px, reported one sixteenth high (residue 15).
        (-1, -2.0),
        # -8 = -1 px + 8/16: only offsets in [7.5, 8] from -1 px round to +8 (residue 8).
        (-8, -8.25),
        # -16 = -1 px exactly: offsets in (-1.5, 0.5) from -1 px (residue 0).
        (-16, -16.5),
        # -20 = -2 px + 12/16: an offset in (-5.5, -4.5] from -1 px (residue 12).
        (-20, -21.0),
    ],
)
def test_decoding_worked_negative_examples(raw, expected):
    assert decoded_sixteenths(np.array([raw], np.int16))[0] == expected


def test_decoding_never_reorders_disparities():
    raw = np.arange(-64, 64, dtype=np.int16)
    assert np.all(np.diff(decoded_sixteenths(raw)) > 0)


def _opencv_sixteenths(d_px: int, numerator: np.ndarray, denom2: int) -> np.ndarray:
    """OpenCV's fixed-point sub-pixel step: d*16 + (num*16 + denom2) / (denom2*2), C division."""
    quotient = np.fix((numerator * 16 + denom2) / (denom2 * 2)).astype(np.int64)
    return (d_px * 16 + quotient).astype(np.int16)


@pytest.mark.parametrize("d_px", [3, -2, 0])
def test_decoding_removes_the_bias_of_opencvs_arithmetic(d_px):
    # Every parabola offset from -8 to +8 sixteenths equally often (num = Sp[d-1] - Sp[d+1] is at
    # most denom2 in size because Sp[d] is the minimum).
    denom2 = 4000
    numerator = np.arange(-denom2, denom2 + 1)
    true = 16 * d_px + 16 * numerator / (2 * denom2)
    raw = _opencv_sixteenths(d_px, numerator, denom2)
    # The truncation: offsets below -1/2 come out 1/2 sixteenth high on average.
    assert np.mean(raw - true) > 0.2
    error = decoded_sixteenths(raw) - true
    assert abs(np.mean(error)) < 1e-3
    for k in range(16):
        at_k = np.mod(raw, 16) == k
        assert abs(np.mean(error[at_k])) < 0.01, k
    assert np.max(np.abs(error)) <= 1.0


def _textured_left(seed: int):
    """A blurred-noise left image (grey levels 128 +- 45) and its pixel grids x, y."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(
        rng.normal(size=(HEIGHT_PX, WIDTH_PX)).astype(np.float32), (0, 0), 1.2
    )
    texture = (texture - texture.mean()) / texture.std()
    left = np.clip(128 + 45 * texture, 0, 255).astype(np.uint8)
    x, y = np.meshgrid(
        np.arange(WIDTH_PX, dtype=np.float32), np.arange(HEIGHT_PX, dtype=np.float32)
    )
    return left, x, y


def _inner() -> np.ndarray:
    inner = np.zeros((HEIGHT_PX, WIDTH_PX), bool)
    inner[BORDER_PX:-BORDER_PX, BORDER_PX:-BORDER_PX] = True
    return inner


@functools.cache
def _slanted_pair(d_left_edge_px: float, d_right_edge_px: float, seed: int = 0):
    """A rectified pair of a textured plane slanted along the rows, and its true disparity.

    The right image samples the left at x + d(x), so the left pixel u = x + d(x) matches the
    right pixel u - d: the module's convention. d is linear in x across the image, so every
    fractional disparity occurs. The plane is slanted along the rows only: SGBM and 3WAY
    aggregate costs along paths that come from the rows above, which drags a disparity that
    changes down the image towards its value a row or two higher, a separate signed effect.
    """
    left, x, y = _textured_left(seed)
    slope = (d_right_edge_px - d_left_edge_px) / WIDTH_PX
    right = cv2.remap(
        left, x + d_left_edge_px + slope * x, y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )
    # Left pixel u matches the right pixel x with x + d(x) = u.
    truth = x - (x - d_left_edge_px) / (1 + slope)
    return left, right, truth, _inner()


def _mean_error_px(disparity: np.ndarray, truth: np.ndarray, inner: np.ndarray) -> float:
    valid = inner & np.isfinite(disparity)
    assert valid.sum() > 0.95 * inner.sum()
    error = disparity[valid] - truth[valid]
    # The right convention matches everywhere (a sign error would not match at all).
    assert np.mean(np.abs(error) < 0.5) > 0.99
    return float(np.mean(error))


def _undecoded(monkeypatch):
    """compute_disparity as it was before the decoding: raw / 16."""
    monkeypatch.setattr(matching, "decoded_sixteenths", lambda raw: raw.astype(np.float32))


@pytest.mark.parametrize(
    ("mode", "d_range_px", "search"),
    [
        ("3WAY", (20, 40), (16, 32)),
        ("SGBM", (20, 40), (16, 32)),
        ("HH4", (20, 40), (16, 32)),
        ("HH", (20, 40), (16, 32)),
        ("3WAY", (-10, 10), (-16, 32)),  # negative raw disparities
    ],
)
def test_mean_disparity_error_is_removed(monkeypatch, mode, d_range_px, search):
    left, right, truth, inner = _slanted_pair(*d_range_px)
    decoded = _mean_error_px(compute_disparity(left, right, *search, mode=mode), truth, inner)
    # Measured: within 0.004 px of zero for every mode, seeds 0..2 and texture scales 1.0-1.5 px.
    assert abs(decoded) < 0.01
    _undecoded(monkeypatch)
    raw = _mean_error_px(compute_disparity(left, right, *search, mode=mode), truth, inner)
    # Measured: +0.023 to +0.030 px (about half a sixteenth on the offsets below -1/2).
    assert raw > 0.02


def test_left_right_check_keeps_the_decoded_disparities():
    # The right-referenced pass is decoded the same way, so the two agree as before.
    left, right, truth, inner = _slanted_pair(20, 40)
    disparity = compute_disparity(left, right, 16, 32, lr_check_max_diff_px=0.5)
    assert abs(_mean_error_px(disparity, truth, inner)) < 0.01


def _parabola_offset(t: np.ndarray) -> np.ndarray:
    """The parabola's offset through three costs that rise linearly from a true offset t."""
    c_minus, c_zero, c_plus = 1 + t, np.abs(t), 1 - t
    return (c_minus - c_plus) / (2 * (c_minus - 2 * c_zero + c_plus))


def test_equiangular_reading_inverts_the_parabola_of_linear_costs():
    t = np.linspace(-0.5, 0.5, 101)
    for whole in (-3.0, 0.0, 25.0):
        np.testing.assert_allclose(
            equiangular_px(whole + _parabola_offset(t)), whole + t, atol=1e-5
        )
    d = np.linspace(-4, 4, 1001, dtype=np.float32)
    assert np.all(np.diff(equiangular_px(d)) > 0)


def _locking_amplitude_px(disparity, truth, inner) -> tuple[float, float]:
    """(mean |error|, mean |bias| over eight bins of the true sub-pixel offset) in pixels."""
    valid = inner & np.isfinite(disparity)
    error = disparity[valid] - truth[valid]
    offset = truth[valid] - np.round(truth[valid])
    bins = np.digitize(offset, np.linspace(-0.5, 0.5, 9)[1:-1])
    return float(np.mean(np.abs(error))), float(
        np.mean([abs(error[bins == b].mean()) for b in range(8)])
    )


@pytest.mark.parametrize("mode", ["3WAY", "SGBM"])
def test_equiangular_reading_weakens_pixel_locking(mode):
    left, right, truth, inner = _slanted_pair(20, 40)
    parabola = _locking_amplitude_px(
        compute_disparity(left, right, 16, 32, mode=mode, subpixel_fit="parabola"), truth, inner
    )
    equiangular = _locking_amplitude_px(
        compute_disparity(left, right, 16, 32, mode=mode), truth, inner
    )
    # Measured (3WAY / SGBM): mean |error| 0.108 -> 0.081 / 0.102 -> 0.075 px, locking
    # amplitude 0.073 -> 0.031 / 0.067 -> 0.025 px.
    assert parabola[1] > 0.06
    assert equiangular[1] < 0.6 * parabola[1]
    assert equiangular[0] < 0.85 * parabola[0]


@functools.cache
def _pair_slanted_down_the_image(d_top_px: float, d_bottom_px: float, seed: int = 0):
    """A rectified pair of a textured plane whose disparity changes down the image only."""
    left, x, y = _textured_left(seed)
    truth = d_top_px + (d_bottom_px - d_top_px) * y / HEIGHT_PX
    right = cv2.remap(left, x + truth, y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return left, right, truth, _inner()


@pytest.mark.parametrize("d_range_px", [(20, 40), (40, 20)])
def test_a_disparity_that_changes_down_the_image_is_followed_by_default(d_range_px):
    left, right, truth, inner = _pair_slanted_down_the_image(*d_range_px)
    for mode in ("HH4", "HH", "3WAY", "SGBM"):
        error = _mean_error_px(compute_disparity(left, right, 16, 32, mode=mode), truth, inner)
        # Measured: HH4 -0.001 px (seed 1: -0.006 / -0.005); 3WAY and SGBM with their
        # upside-down pass -0.001 / +0.002 px.
        assert abs(error) < 0.015, mode


@pytest.mark.parametrize("d_range_px", [(20, 40), (40, 20)])
def test_one_way_modes_lag_behind_without_the_upward_pass(d_range_px):
    left, right, truth, inner = _pair_slanted_down_the_image(*d_range_px)
    # 3WAY's and SGBM's paths come from the rows above only: their match lags by about a row
    # (measured 3WAY -0.038 / +0.037 px, SGBM -0.067 / +0.065 px at 0.042 px per row), with the
    # sign of the change. This is what the upward pass cancels.
    for mode in ("3WAY", "SGBM"):
        disparity = compute_disparity(left, right, 16, 32, mode=mode, upward_pass=False)
        error = _mean_error_px(disparity, truth, inner)
        assert error * np.sign(d_range_px[1] - d_range_px[0]) < -0.025, mode


def test_the_two_passes_are_averaged_and_marked_where_they_agree():
    nan = np.nan
    downward = np.array([[10.0, 10.0, nan, 10.0, nan]], np.float32)
    upward = np.array([[10.4, 13.0, 11.0, nan, nan]], np.float32)
    merged, agreed = with_upward_pass(downward, upward)
    # Agreeing: the mean; disagreeing: the usual pass; one missing: the other; both: none.
    np.testing.assert_allclose(merged[0, :4], [10.2, 10.0, 11.0, 10.0])
    assert np.isnan(merged[0, 4])
    assert agreed.tolist() == [[True, False, False, False, False]]


def test_pixels_where_the_passes_disagree_are_dropped_after_the_filters(monkeypatch):
    left, _, _, inner = _slanted_pair(20, 40)
    downward = np.full(left.shape, 30.0, np.float32)
    upward = downward.copy()
    upward[100:140, 100:140] = 33.0  # disagrees by 3 px
    upward[200:240, 200:240] = np.nan  # the upward pass found nothing
    passes = iter([downward, upward[::-1]])  # the upward pass sees the pair upside down
    monkeypatch.setattr(matching, "_sgbm", lambda *args: next(passes).copy())
    disparity = compute_disparity(left, left, 16, 32)
    dropped = np.zeros(left.shape, bool)
    dropped[100:140, 100:140] = dropped[200:240, 200:240] = True
    assert np.isnan(disparity[dropped]).all()
    # Everywhere else the textured pair keeps the common value.
    assert np.nanmax(np.abs(disparity[inner & ~dropped] - 30.0)) == 0
    assert np.isfinite(disparity[inner & ~dropped]).mean() > 0.99

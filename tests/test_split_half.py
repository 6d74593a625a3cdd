"""Split-half agreement against samplings with a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.evaluation.split_half import split_half_agreement

SIGMA_M = 0.1e-3  # noise along the normal in each half
PITCH_M = 2.0e-3  # grid pitch, 20 sigma: a point's nearest neighbour is its counterpart


def _grid(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    x, y = np.meshgrid(x_m, y_m)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def test_noisy_halves_of_one_plane_give_the_noise_median_and_p90():
    rng = np.random.default_rng(0)
    grid = _grid(np.arange(150) * PITCH_M, np.arange(150) * PITCH_M)
    even, odd = grid.copy(), grid.copy()
    even[:, 2] = rng.normal(0.0, SIGMA_M, len(grid))
    odd[:, 2] = rng.normal(0.0, SIGMA_M, len(grid))
    result = split_half_agreement(even, odd, common_radius_m=10 * SIGMA_M)
    # |N(0, 2 sigma^2)|: median sqrt(2) * 0.6745 sigma, p90 sqrt(2) * 1.6449 sigma; 22,500
    # samples give the quantiles within about 1.5 %.
    assert result.median_m == pytest.approx(np.sqrt(2) * 0.6745 * SIGMA_M, rel=0.03)
    assert result.p90_m == pytest.approx(np.sqrt(2) * 1.6449 * SIGMA_M, rel=0.03)
    assert result.common_share == pytest.approx(1.0, abs=1e-4)


def test_partly_overlapping_patches_give_the_overlap_share():
    # Even covers x in [0, 100) pitches, odd [60, 160): 40 of each half's 100 columns overlap.
    y = np.arange(50) * PITCH_M
    even = _grid(np.arange(0, 100) * PITCH_M, y)
    odd = _grid(np.arange(60, 160) * PITCH_M, y)
    odd[:, 2] += 0.05e-3  # a known offset on the overlap
    result = split_half_agreement(even, odd, common_radius_m=0.3 * PITCH_M)
    assert result.common_share == pytest.approx(0.4, abs=1e-9)
    assert result.median_m == pytest.approx(0.05e-3, abs=1e-9)
    assert result.p90_m == pytest.approx(0.05e-3, abs=1e-9)


def test_halves_with_nothing_in_common_share_nothing():
    even = _grid(np.arange(10) * PITCH_M, np.arange(10) * PITCH_M)
    odd = even + np.array([0.0, 0.0, 0.01])
    result = split_half_agreement(even, odd, common_radius_m=1e-3)
    assert result.common_share == 0.0
    assert np.isnan(result.median_m)


def test_an_empty_half_or_a_bad_radius_is_a_user_error():
    cloud = np.zeros((3, 3))
    with pytest.raises(ScannerError, match="both halves"):
        split_half_agreement(cloud, np.zeros((0, 3)), 1e-3)
    with pytest.raises(ScannerError, match="common_radius_m"):
        split_half_agreement(cloud, cloud, 0.0)


def test_along_the_normal_two_samplings_of_one_plane_agree_where_nearest_points_do_not():
    # The same plane sampled by two grids half a pitch apart, noise free: nearest neighbours
    # lie 0.71 pitch apart, the surfaces not at all.
    grid = _grid(np.arange(60) * PITCH_M, np.arange(60) * PITCH_M)
    odd = grid + np.array([0.5 * PITCH_M, 0.5 * PITCH_M, 0.0])
    result = split_half_agreement(grid, odd, common_radius_m=PITCH_M)
    assert result.median_m == pytest.approx(np.sqrt(0.5) * PITCH_M, rel=1e-6)
    assert result.normal_median_m == pytest.approx(0.0, abs=1e-12)
    # A known offset of one half along the normal is the normal distance, wherever it samples.
    result = split_half_agreement(grid, odd + np.array([0.0, 0.0, 0.05e-3]), PITCH_M)
    assert result.normal_median_m == pytest.approx(0.05e-3, rel=1e-6)
    assert result.normal_p90_m == pytest.approx(0.05e-3, rel=1e-6)


def test_along_the_normal_noisy_halves_give_one_halfs_noise_and_the_others_plane_fit():
    rng = np.random.default_rng(1)
    grid = _grid(np.arange(150) * PITCH_M, np.arange(150) * PITCH_M)
    even, odd = grid.copy(), grid + np.array([0.5 * PITCH_M, 0.0, 0.0])
    even[:, 2] = rng.normal(0.0, SIGMA_M, len(grid))
    odd[:, 2] = rng.normal(0.0, SIGMA_M, len(grid))
    result = split_half_agreement(even, odd, common_radius_m=PITCH_M)
    # A point's own noise (sigma) and the 12-point plane's error at it (about sigma / sqrt(12)
    # at its centre, more off it): the median lies between sqrt(2) * 0.6745 sigma
    # (the nearest point's) and 0.6745 sigma (a perfect plane).
    assert 0.6745 * SIGMA_M < result.normal_median_m < np.sqrt(2) * 0.6745 * SIGMA_M

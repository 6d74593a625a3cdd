"""Agreement of two independent halves of a reconstruction: a precision measure without a
reference surface.

The views are split in two (even and odd reference views) and each half is reconstructed
alone. Where both halves hold the surface, their distance is the reconstruction's own scatter:
with normal noise of deviation sigma along the surface's normal in each half, a point's distance
to its counterpart at the same place in the other half is |N(0, 2 sigma^2)|, median
0.954 sigma (= sqrt(2) x 0.674 sigma), p90 2.33 sigma. The nearest of many noisy neighbours is a
little nearer than the counterpart, and a sparse half adds its in-plane spacing. It says
nothing of a bias both halves share (a wrong scale or calibration), which only a reference can
show.

Only the common part is measured: a point whose nearest neighbour in the other half lies
farther than `common_radius_m` is a part that half did not see (or an outlier), whose distance
measures coverage, not precision; the share of points in the common part reports that instead.
The radius must exceed the scatter (a few sigma) and stay below the size of what one half may
miss alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.common.errors import ScannerError
from reconstruction.common.kdtree import query_workers


@dataclass(frozen=True)
class SplitHalf:
    """Nearest-neighbour distances between the halves on their common part (metres): median and
    90th percentile over both directions' points; common_share: the share of all points of both
    halves that lie in the common part."""

    median_m: float
    p90_m: float
    common_share: float


def _distances_m(points_W: np.ndarray, other_W: np.ndarray, radius_m: float) -> np.ndarray:
    tree = cKDTree(other_W)
    # Beyond the radius the distance is not needed: the point is outside the common part.
    d, _ = tree.query(
        points_W, k=1, distance_upper_bound=radius_m, workers=query_workers(len(points_W))
    )
    return d


def split_half_agreement(
    cloud_even_W: np.ndarray, cloud_odd_W: np.ndarray, common_radius_m: float
) -> SplitHalf:
    """Distances from each half (N, 3) and (M, 3), metres, to the other, symmetric: the points
    of both halves whose nearest neighbour in the other half is within `common_radius_m`."""
    even = np.asarray(cloud_even_W, float).reshape(-1, 3)
    odd = np.asarray(cloud_odd_W, float).reshape(-1, 3)
    if len(even) == 0 or len(odd) == 0:
        raise ScannerError(
            f"split_half_agreement: both halves need points (even {len(even)}, odd {len(odd)})"
        )
    if not common_radius_m > 0.0:
        raise ScannerError(
            f"split_half_agreement: common_radius_m must be > 0, got {common_radius_m}"
        )
    d = np.concatenate(
        [_distances_m(even, odd, common_radius_m), _distances_m(odd, even, common_radius_m)]
    )
    common = d <= common_radius_m
    if not common.any():
        return SplitHalf(float("nan"), float("nan"), 0.0)
    return SplitHalf(
        median_m=float(np.median(d[common])),
        p90_m=float(np.percentile(d[common], 90)),
        common_share=float(np.count_nonzero(common) / len(d)),
    )

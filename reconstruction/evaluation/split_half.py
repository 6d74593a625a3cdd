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

The nearest neighbour mixes two things: how far the halves' surfaces lie apart, and how far
two samplings of one surface lie beside each other (about half the spacing, whatever the
precision). The distance along the other half's surface normal (a plane through the point's
nearest `NORMAL_NEIGHBOURS` there) keeps the first alone; both are given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.common.errors import ScannerError
from reconstruction.common.kdtree import query_workers

# Neighbours of the other half that fit its local plane: enough to average its noise, few
# enough to stay on one side of an edge at the halves' spacing.
NORMAL_NEIGHBOURS = 12
# Points queried at a time (their neighbours: 12 x 3 doubles each).
CHUNK = 200_000


@dataclass(frozen=True)
class SplitHalf:
    """Nearest-neighbour distances between the halves on their common part (metres): median and
    90th percentile over both directions' points; common_share: the share of all points of both
    halves that lie in the common part. normal_median_m / normal_p90_m: the same points'
    distances along the other half's local surface normal."""

    median_m: float
    p90_m: float
    common_share: float
    normal_median_m: float = float("nan")
    normal_p90_m: float = float("nan")


def _distances_m(
    points_W: np.ndarray, other_W: np.ndarray, radius_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per point, the distance to the nearest point of `other_W` (inf beyond `radius_m`: not
    in the common part) and to the plane of its nearest neighbours there (nan beyond)."""
    tree = cKDTree(other_W)
    workers = query_workers(len(points_W))
    k = min(NORMAL_NEIGHBOURS, len(other_W))
    d = np.empty(len(points_W))
    along = np.full(len(points_W), np.nan)
    # One query a chunk: the nearest of the neighbours is the nearest point.
    for start in range(0, len(points_W), CHUNK):
        rows = slice(start, start + CHUNK)
        near, idx = tree.query(points_W[rows], k=k, workers=workers)
        near, idx = near.reshape(len(near), -1), idx.reshape(len(idx), -1)
        d[rows] = near[:, 0]
        common = near[:, 0] <= radius_m
        if k < 3 or not common.any():
            continue
        nb = other_W[idx[common]]
        centre = nb.mean(axis=1)
        spread = nb - centre[:, None, :]
        # The plane's normal: the least-spread direction of the neighbours.
        normal = np.linalg.eigh(np.einsum("nki,nkj->nij", spread, spread))[1][:, :, 0]
        p = points_W[rows][common]
        along[start + np.flatnonzero(common)] = np.abs(np.einsum("ni,ni->n", p - centre, normal))
    # Beyond the radius the point is outside the common part.
    d[d > radius_m] = np.inf
    return d, along
    for start in range(0, len(common), CHUNK):
        rows = common[start : start + CHUNK]
        _, idx = tree.query(points_W[rows], k=k, workers=workers)
        nb = other_W[idx.reshape(len(rows), k)]
        centre = nb.mean(axis=1)
        spread = nb - centre[:, None, :]
        # The plane's normal: the least-spread direction of the neighbours.
        normal = np.linalg.eigh(np.einsum("nki,nkj->nij", spread, spread))[1][:, :, 0]
        along[rows] = np.abs(np.einsum("ni,ni->n", points_W[rows] - centre, normal))
    return d, along


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
    (d_even, n_even), (d_odd, n_odd) = (
        _distances_m(even, odd, common_radius_m),
        _distances_m(odd, even, common_radius_m),
    )
    d, along = np.concatenate([d_even, d_odd]), np.concatenate([n_even, n_odd])
    common = d <= common_radius_m
    if not common.any():
        return SplitHalf(float("nan"), float("nan"), 0.0)
    normal = along[common]
    normal = normal[np.isfinite(normal)]
    return SplitHalf(
        median_m=float(np.median(d[common])),
        p90_m=float(np.percentile(d[common], 90)),
        common_share=float(np.count_nonzero(common) / len(d)),
        normal_median_m=float(np.median(normal)) if len(normal) else float("nan"),
        normal_p90_m=float(np.percentile(normal, 90)) if len(normal) else float("nan"),
    )

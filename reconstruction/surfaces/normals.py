"""The fused cloud's own local planes: smoother normals, and the points that lie off them.

Each view estimates its normals from its own noisy points (3 mm neighbourhoods); the fused cloud
averages those, so their noise reaches Poisson, which integrates normals into the surface: the
stereo noise shows as bumps. The fused points are already averaged over the views, so a plane
fitted to them over a wider neighbourhood gives a smoother normal. Only neighbours whose own
normal agrees with the point's take part, so the two sides of a thin wall and the two faces of a
sharp edge keep their own normals.

The same planes show which fused points lie well off the surface their neighbours describe:
stereo mismatches at occluding edges and grazing views that survived each view's own filters.
Poisson bends towards them; they are dropped beyond a multiple of the residuals' robust spread.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# Fewer agreeing neighbours than this: the plane is not trusted and the normal stays.
MIN_NEIGHBOURS = 6
# Points per batch: bounds the (batch, neighbours, 3) arrays to about 10 MB each.
BATCH = 8192
# Threads over the batches (one KD-tree query thread each: a batch is below the size where a
# parallel query pays, `reconstruction.common.kdtree`).
PLANE_THREADS = min(os.cpu_count() or 1, 8)
# Median of |x| for a zero-mean normal x is 0.6745 sigma.
MAD_TO_SIGMA = 1.0 / 0.6745


@dataclass(frozen=True, eq=False)
class LocalPlanes:
    """Per point: the unit normal of its neighbours' plane (signed like the given normal) and its
    distance from that plane (m; NaN where too few neighbours agree)."""

    normals: np.ndarray
    residuals_m: np.ndarray


def local_planes(
    points: np.ndarray,
    normals: np.ndarray,
    radius_m: float,
    min_agreement_cos: float = 0.5,
    max_neighbours: int = 24,
) -> LocalPlanes:
    """The plane through each point's neighbours within `radius_m` whose normals make less than
    arccos(min_agreement_cos) with its own (the point included). Points with fewer than
    MIN_NEIGHBOURS such neighbours keep their normal and get a NaN residual.

    At most `max_neighbours` (the nearest): 24 gave the same bunny as 48 (observed Chamfer
    0.1575 / 0.1584 mm) in 1.6 instead of 2.3 s for 117k points."""
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    out = normals.copy()
    residuals = np.full(len(points), np.nan)
    if len(points) < MIN_NEIGHBOURS or radius_m <= 0:
        return LocalPlanes(out, residuals)
    tree = cKDTree(points)
    k = min(max_neighbours, len(points))

    def batch(start: int) -> None:
        stop = min(start + BATCH, len(points))
        dist, idx = tree.query(points[start:stop], k=k, distance_upper_bound=radius_m)
        found = np.isfinite(dist)
        idx = np.where(found, idx, 0)
        own = normals[start:stop]
        agree = np.einsum("ij,ikj->ik", own, normals[idx]) > min_agreement_cos
        weight = (found & agree).astype(np.float64)
        count = weight.sum(axis=1)
        # Coordinates relative to the point itself: no cancellation far from the origin.
        near = points[idx] - points[start:stop, None, :]
        weighted = near * weight[:, :, None]
        mean = weighted.sum(axis=1) / np.maximum(count, 1.0)[:, None]
        cov = weighted.transpose(0, 2, 1) @ near - count[:, None, None] * (
            mean[:, :, None] * mean[:, None, :]
        )
        _, vectors = np.linalg.eigh(cov)
        n = vectors[:, :, 0]
        n *= np.where(np.einsum("ij,ij->i", n, own) < 0, -1.0, 1.0)[:, None]
        trusted = count >= MIN_NEIGHBOURS
        out[start:stop][trusted] = n[trusted]
        residuals[start:stop][trusted] = np.abs(np.einsum("ij,ij->i", mean, n))[trusted]

    # The batches are independent and each writes its own rows; the query and numpy's loops
    # release the GIL, so threads share them out (a fused cloud of 127k points: 1.0 -> 0.5 s
    # on two cores, the same normals and residuals bit for bit). It runs after the last
    # picture, on the way to the model.
    with ThreadPoolExecutor(max_workers=PLANE_THREADS) as pool:
        list(pool.map(batch, range(0, len(points), BATCH)))
    return LocalPlanes(out, residuals)


def off_surface(residuals_m: np.ndarray, sigmas: float) -> np.ndarray:
    """True for points farther from their local plane than `sigmas` robust standard deviations
    of all residuals (1.4826 x their median); none when sigmas is 0 or nothing was fitted."""
    finite = np.isfinite(residuals_m)
    if sigmas <= 0 or not finite.any():
        return np.zeros(len(residuals_m), bool)
    limit = sigmas * MAD_TO_SIGMA * float(np.median(residuals_m[finite]))
    return finite & (residuals_m > limit)

"""Voxel averaging in NumPy: the points of each occupied cell of a regular grid replaced by
their mean, and any per-point attributes (normals, colours) by theirs.

Open3D's `voxel_down_sample` does the same on its own grid, but reaching it means copying every
point, normal and colour into Open3D's vectors first: on the 1.8 million points, normals and
colours of a 48-view scan's fusion, copy and averaging took 0.47 s against 0.37 s for sorting the
cells' keys and summing with `np.bincount` (warm; the first touch of the arrays' memory costs
either more on a virtual machine). The grid is Open3D's (cells of `voxel_m` from
half a cell below the points' minimum corner), so the same points share a cell; the cells come
out in the order of their keys, the same for the same input.
"""

from __future__ import annotations

import numpy as np

from reconstruction.common.errors import ScannerError


def voxel_means(
    points: np.ndarray, voxel_m: float, *attributes: np.ndarray
) -> tuple[np.ndarray, ...]:
    """(means of `points` per occupied cell (M, 3), then the mean of each attribute per cell
    (M, k) as float64). points: (N, 3) metres; attributes: (N, k) each."""
    points = np.asarray(points, np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ScannerError(f"voxel_means: points (N, 3) expected, got {points.shape}")
    if not voxel_m > 0:
        raise ScannerError(f"voxel_means: voxel_m must be > 0, got {voxel_m}")
    for a in attributes:
        if len(a) != len(points):
            raise ScannerError(
                f"voxel_means: an attribute has {len(a)} rows for {len(points)} points"
            )
    if not len(points):
        return (points.reshape(0, 3), *(np.zeros((0, *np.shape(a)[1:])) for a in attributes))
    cell = np.floor((points - (points.min(axis=0) - 0.5 * voxel_m)) / voxel_m).astype(np.int64)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    out = []
    for values in (points, *attributes):
        values = np.asarray(values, np.float64).reshape(len(points), -1)
        sums = np.stack(
            [
                np.bincount(inverse, weights=values[:, j], minlength=len(counts))
                for j in range(values.shape[1])
            ],
            axis=1,
        )
        out.append(sums / counts[:, None])
    return tuple(out)

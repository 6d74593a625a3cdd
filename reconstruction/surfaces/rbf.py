"""An implicit surface from oriented points: a radial basis function (RBF) fitted to the fused
cloud, meshed by marching cubes at its zero level (metres, world frame W).

After Carr et al., "Reconstruction and representation of 3D objects with radial basis
functions" (SIGGRAPH 2001): the function is 0 on the surface points and +offset / -offset at
points moved by the offset along / against their normals. The fused cloud's normals face the
cameras, i.e. out of the object, so the function is negative inside and grows outwards, about a
signed distance near the data. Centres are a voxel thinning of the cloud, and each evaluation
uses only its nearest centres (scipy's local RBF), so the cost grows with the area, not its
square. An RBF extrapolates everywhere: it is evaluated only in a band around the data, and
triangles farther than `max_distance_m` from every point are dropped, as Poisson's are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.ndimage import binary_dilation
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

from reconstruction.common.errors import ScannerError
from reconstruction.surfaces.topology import kept_triangles

RBF_KERNELS = ("thin_plate_spline", "linear", "cubic")
# Grid points evaluated per call to the interpolant: bounds the (chunk, neighbours) index and
# distance arrays scipy builds to a few hundred MB at 64 neighbours.
_CHUNK_POINTS = 50_000
# A grid over a bounding box with more cells than this is a configuration error (a voxel far
# finer than the data), not a surface to compute: 2e8 cells are 1.6 GB of float64 values.
_MAX_GRID_CELLS = 200_000_000


@dataclass(frozen=True)
class RbfParams:
    """How the RBF surface is fitted and meshed (SurfaceConfig's rbf_* fields)."""

    centre_spacing_m: float  # voxel of the thinning that gives the centres
    max_centres: int  # the spacing grows until at most this many centres remain
    offset_m: float  # distance of the off-surface constraints along the normals
    kernel: str  # one of RBF_KERNELS
    neighbors: int  # centres (with their off-surface points) each evaluation uses
    smoothing: float  # scipy's smoothing, in units of the centre spacing
    voxel_size_m: float  # marching-cubes grid
    max_distance_m: float  # triangles farther than this from every point are dropped


@dataclass(frozen=True, eq=False)
class RbfSurface:
    """Vertices (V, 3) m in W, triangles (M, 3) facing out of the object, the number of
    centres fitted and the spacing of their thinning (m)."""

    vertices: np.ndarray
    triangles: np.ndarray
    centres: int
    centre_spacing_m: float


def voxel_thin(
    points: np.ndarray, normals: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Mean point and re-normalised mean normal of each occupied voxel, voxels in lexicographic
    order of their index (one order for one input)."""
    keys = np.floor(points / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    p = np.zeros((len(counts), 3))
    n = np.zeros((len(counts), 3))
    np.add.at(p, inverse, points)
    np.add.at(n, inverse, normals)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return p / counts[:, None], n


def thin_to_centres(
    points: np.ndarray, normals: np.ndarray, spacing_m: float, max_centres: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """Voxel thinning at `spacing_m`, coarsened by 25 % steps until at most `max_centres`
    remain. Returns (centres, normals, spacing used)."""
    while True:
        centres, centre_normals = voxel_thin(points, normals, spacing_m)
        if len(centres) <= max_centres:
            return centres, centre_normals, spacing_m
        spacing_m *= 1.25


def constraints(
    centres: np.ndarray, normals: np.ndarray, offset_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Points (3N, 3) and their function values (3N,): 0 on the centres, +offset outside
    (along the normals), -offset inside."""
    points = np.vstack([centres, centres + offset_m * normals, centres - offset_m * normals])
    values = np.concatenate([np.zeros(len(centres)), np.full(len(centres), offset_m)])
    return points, np.concatenate([values, np.full(len(centres), -offset_m)])


def band_grid(points: np.ndarray, voxel_m: float, band_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A grid over the points' bounding box (padded by the band): its origin (3,) m and the
    mask (I, J, K) of grid points within about `band_m` of a point (the voxels holding points,
    dilated by a ball of that radius)."""
    reach = int(np.ceil(band_m / voxel_m))
    origin = points.min(axis=0) - (reach + 2) * voxel_m
    shape = np.floor((points.max(axis=0) - origin) / voxel_m).astype(np.int64) + reach + 3
    if int(np.prod(shape)) > _MAX_GRID_CELLS:
        raise ScannerError(
            f"surfaces.rbf_voxel_size_m: {voxel_m:g} m makes a grid of {int(np.prod(shape))} "
            f"cells over the cloud (at most {_MAX_GRID_CELLS}); expected a coarser voxel"
        )
    mask = np.zeros(tuple(shape), bool)
    index = np.round((points - origin) / voxel_m).astype(np.int64)
    mask[index[:, 0], index[:, 1], index[:, 2]] = True
    r = np.arange(-reach, reach + 1)
    ball = (r[:, None, None] ** 2 + r[None, :, None] ** 2 + r[None, None, :] ** 2) <= reach**2
    return origin, binary_dilation(mask, structure=ball)


def _evaluate(
    interpolant: RBFInterpolator, grid_points: np.ndarray, chunk: int = _CHUNK_POINTS
) -> np.ndarray:
    return np.concatenate(
        [interpolant(grid_points[i : i + chunk]) for i in range(0, len(grid_points), chunk)]
    )


def cut_to_data(
    vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray, max_distance_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Triangles with a vertex farther than `max_distance_m` from every point dropped, and
    vertices no longer used."""
    d, _ = cKDTree(points).query(vertices, distance_upper_bound=max_distance_m)
    return kept_triangles(vertices, triangles, np.isfinite(d)[triangles].all(axis=1))


def rbf_surface(points: np.ndarray, normals: np.ndarray, params: RbfParams) -> RbfSurface:
    """The zero level of an RBF fitted to oriented points (N, 3) m with unit normals facing
    out, where the data are (see the module docstring). Deterministic: the same input gives
    the same arrays."""
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    if len(points) < 10:
        raise ScannerError(f"RBF: only {len(points)} fused points, nothing to mesh")
    centres, centre_normals, spacing = thin_to_centres(
        points, normals, params.centre_spacing_m, params.max_centres
    )
    y, d = constraints(centres, centre_normals, params.offset_m)
    # Coordinates and values in units of the centre spacing around the cloud's centre: the
    # kernels' scale and `smoothing` then do not depend on the object's size or position.
    shift = 0.5 * (points.min(axis=0) + points.max(axis=0))
    interpolant = RBFInterpolator(
        (y - shift) / spacing,
        d / spacing,
        neighbors=min(3 * params.neighbors, len(y)),
        smoothing=params.smoothing,
        kernel=params.kernel,
    )
    # One voxel beyond the cut, so that every cell marching cubes visits has its 8 corners
    # evaluated (a corner left unset would make a false crossing).
    band_m = params.max_distance_m + params.voxel_size_m
    origin, mask = band_grid(points, params.voxel_size_m, band_m)
    evaluated = binary_dilation(mask, structure=np.ones((3, 3, 3), bool))
    ijk = np.argwhere(evaluated)
    grid_points = origin + ijk * params.voxel_size_m
    values = np.full(mask.shape, params.offset_m / spacing)
    values[tuple(ijk.T)] = _evaluate(interpolant, (grid_points - shift) / spacing)
    if not (values[mask].min() < 0 < values[mask].max()):
        return RbfSurface(np.zeros((0, 3)), np.zeros((0, 3), np.int64), len(centres), spacing)
    # Our function grows outwards, which skimage calls "ascent", yet "ascent" wound the
    # triangles of a sphere inwards: "descent" makes them face out (checked in the tests).
    verts, faces, _, _ = marching_cubes(
        values,
        level=0.0,
        spacing=(params.voxel_size_m,) * 3,
        gradient_direction="descent",
        allow_degenerate=False,
        mask=mask,
    )
    vertices, triangles = cut_to_data(
        origin + verts.astype(np.float64), faces.astype(np.int64), points, params.max_distance_m
    )
    return RbfSurface(vertices, triangles, len(centres), spacing)

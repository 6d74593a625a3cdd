"""Where the object is, without a cell model: a sphere in W from the object masks (a coarse
visual hull) or, without masks, from the cameras' common view; or a sphere or a box the user
gives.

A robot cell knows where the object hangs; a recording from another system does not. The
depth window of every stereo pair and the crop of every view follow from this sphere, so it
must hold the whole object, and should hold little else: a sphere ten times too large only
costs matching time, one too small cuts the object.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points


@dataclass(frozen=True, eq=False)
class PosedCamera:
    """One view's pinhole camera (K in pixels, image width x height) at X_WC (metres)."""

    K: np.ndarray
    X_WC: np.ndarray
    width: int
    height: int


@dataclass(frozen=True, eq=False)
class WorkingVolume:
    """A sphere in W (metres) that holds the object, and how it was found; for a box the user
    gave (axis-aligned in W), the box's half extents too, with the sphere around it: the depth
    windows and crops follow the sphere, the points kept follow the box."""

    centre_W: np.ndarray
    radius_m: float
    source: str  # "masks", "common view", "given", "given box"
    half_extent_m: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        centre = np.asarray(self.centre_W, float)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise ScannerError(f"working volume: centre must be three finite numbers, got {centre}")
        if not (math.isfinite(self.radius_m) and self.radius_m > 0):
            raise ScannerError(f"working volume: radius must be positive, got {self.radius_m} m")
        centre.setflags(write=False)
        object.__setattr__(self, "centre_W", centre)


def volume_of_box(lo_W: Sequence[float], hi_W: Sequence[float]) -> WorkingVolume:
    """The working volume of an axis-aligned box in W (its two opposite corners, metres)."""
    lo, hi = np.asarray(lo_W, float), np.asarray(hi_W, float)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(np.r_[lo, hi])):
        raise ScannerError("working volume: a box needs two corners of three finite numbers")
    if not np.all(hi > lo):
        raise ScannerError(
            f"working volume: a box's second corner must exceed its first in x, y and z, got "
            f"{lo.tolist()} and {hi.tolist()}"
        )
    half = (hi - lo) / 2
    return WorkingVolume(
        (lo + hi) / 2, float(np.linalg.norm(half)), "given box", tuple(map(float, half))
    )


def project(camera: PosedCamera, p_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of world points and their depth along the optical axis (N,)."""
    p_C = transform_points(invert(camera.X_WC), p_W)
    z = p_C[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (p_C[:, :2] / z[:, None]) * np.diag(camera.K)[:2] + camera.K[:2, 2]
    return uv, z


def common_view_centre(cameras: Sequence[PosedCamera]) -> np.ndarray:
    """The point closest (least squares) to every camera's optical axis: what a set of views
    aimed at one object looks at. Needs two axes that are not parallel."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        axis = cam.X_WC[:3, 2] / np.linalg.norm(cam.X_WC[:3, 2])
        P = np.eye(3) - np.outer(axis, axis)  # distance to the axis, squared, is |P (x - c)|^2
        A += P
        b += P @ cam.X_WC[:3, 3]
    if len(cameras) < 2 or np.linalg.cond(A) > 1e8:
        raise ScannerError(
            "working volume: the cameras' optical axes are parallel or too few (need two that "
            "converge): give the volume (a sphere) instead"
        )
    return np.linalg.solve(A, b)


def volume_from_common_view(cameras: Sequence[PosedCamera]) -> WorkingVolume:
    """The sphere about the axes' common point that holds everything a view sees at that
    point's depth: its radius is the largest, over the views, of the distance to the centre
    times the tangent of the angle to the farthest image corner. A robot's views of one object
    frame it, and an object may fill (and overflow) every frame: the sphere must hold what any
    view shows of it, not what all of them show whole; beyond it lies the background."""
    centre = common_view_centre(cameras)
    radii = []
    for cam in cameras:
        (uv,), (z,) = project(cam, centre[None])
        if not z > 0:
            raise ScannerError("working volume: the cameras' common point lies behind a camera")
        corners = np.array([[0, 0], [cam.width, 0], [0, cam.height], [cam.width, cam.height]])
        reach_px = np.linalg.norm(corners - uv, axis=1).max()
        radii.append(z * reach_px / min(cam.K[0, 0], cam.K[1, 1]))
    return WorkingVolume(centre, float(max(radii)), "common view")


def volume_from_masks(
    cameras: Sequence[PosedCamera],
    masks: Sequence[np.ndarray],
    search: WorkingVolume,
    cells: int = 48,
    margin_m: float = 0.0,
) -> WorkingVolume:
    """The bounding sphere of the masks' visual hull: the cells of a grid over `search` (e.g.
    the common view) that project inside every mask (or outside a view's image: that view says
    nothing of them). The hull holds the object whatever the masks' detail; the grid's cell
    (and `margin_m`) is added to the radius so that carving on cell centres cuts nothing.
    masks: (H, W) per camera, non-zero = object."""
    if len(masks) != len(cameras):
        raise ScannerError(f"working volume: {len(masks)} masks for {len(cameras)} cameras")
    step = 2 * search.radius_m / cells
    axis = (np.arange(cells) + 0.5) * step - search.radius_m
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    grid = grid[np.einsum("ij,ij->i", grid, grid) <= search.radius_m**2] + search.centre_W
    keep = np.ones(len(grid), bool)
    # A cell no view sees is not known to be object: it must lie in enough images (a quarter
    # of them, at least two), and inside the mask of every one it lies in.
    seen_by = np.zeros(len(grid), int)
    for cam, mask in zip(cameras, masks, strict=True):
        mask = np.asarray(mask)
        if mask.shape != (cam.height, cam.width):
            raise ScannerError(
                f"working volume: a mask is {mask.shape[1]}x{mask.shape[0]}, its image "
                f"{cam.width}x{cam.height}"
            )
        uv, z = project(cam, grid[keep])
        u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        inside = (z > 0) & (u >= 0) & (v >= 0) & (u < cam.width) & (v < cam.height)
        seen_by[keep] += inside
        hit = np.ones(len(u), bool)
        hit[inside] = mask[v[inside], u[inside]] > 0
        keep[np.flatnonzero(keep)[~hit]] = False
    keep &= seen_by >= max(2, math.ceil(len(cameras) / 4))
    if not keep.any():
        raise ScannerError(
            "working volume: no point projects inside every mask: the masks do not belong to "
            "these cameras, or the object lies outside the cameras' common view"
        )
    hull = grid[keep]
    lo, hi = hull.min(axis=0), hull.max(axis=0)
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hull - centre, axis=1).max()) + math.sqrt(3) * step + margin_m
    # Views from one side leave the hull open in depth, cut only by the search sphere: its
    # sphere is then hardly smaller, but centred on the object, not on the axes' common point.
    return WorkingVolume(centre, radius, "masks")

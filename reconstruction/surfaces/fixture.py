"""The model-side guard against the fixture: what holds the object (a rod hung from above) must
never enter the model.

Each view's cloud is cleaned of the rod by the caller's geometry filter, at the pose the view
was filtered with and again at its final pose. This guard looks at the model itself: along the
fixture's line, above the centre of the hanging, every slice of the fused cloud that holds
nothing but a thin strip around the line (no surface spreading out around it) is the fixture,
not the object, and is cut. The object begins at the highest slice where points spread out
around the line; nothing below that is touched, so the object's own top (where it is clamped)
stays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.transforms import transform_points


@dataclass(frozen=True)
class FixtureLine:
    """The fixture's axis in a hanging's world frame: it leaves the object upwards from
    `p_W` (a point on the axis at the height of the hanging's centre) along the unit `u_W`;
    `radius_m` is the rod's."""

    p_W: tuple[float, float, float]
    u_W: tuple[float, float, float]
    radius_m: float

    def moved(self, T: np.ndarray) -> FixtureLine:
        """The same line after the rigid transform T (4x4) of its hanging's points."""
        T = np.asarray(T, float)
        p = transform_points(T, np.asarray([self.p_W], float))[0]
        u = T[:3, :3] @ np.asarray(self.u_W, float)
        return FixtureLine(tuple(map(float, p)), tuple(map(float, u)), self.radius_m)


@dataclass(frozen=True)
class FixtureGuard:
    """How the guard tells the fixture from the object (metres).

    margin_m: points within the rod's radius plus this of the axis are the strip (covers the
    stereo error at grazing angles). ring_m: how far beyond the strip a slice is searched for
    surface spreading around the line. slice_m: the slices' height. min_ring_points: points in
    a slice's ring that make it the object's (a few stray points do not)."""

    margin_m: float = 0.008
    ring_m: float = 0.02
    slice_m: float = 0.004
    min_ring_points: int = 12


def fixture_points(
    points_W: np.ndarray, line: FixtureLine, guard: FixtureGuard = FixtureGuard()
) -> np.ndarray:
    """Mask (N,) of the points that belong to the fixture's strip above the object, with the
    few stray points around it there."""
    p = np.asarray(points_W, float) - np.asarray(line.p_W, float)
    u = np.asarray(line.u_W, float) / np.linalg.norm(line.u_W)
    along = p @ u
    across = np.linalg.norm(p - np.outer(along, u), axis=1)
    strip_r = line.radius_m + guard.margin_m
    above = along > 0
    strip = above & (across < strip_r)
    if not strip.any():
        return strip
    ring = above & (across >= strip_r) & (across < strip_r + guard.ring_m)
    slices = np.floor(along[ring] / guard.slice_m).astype(int)
    counts = np.bincount(slices) if len(slices) else np.zeros(0, int)
    solid = np.flatnonzero(counts >= guard.min_ring_points)
    # The object ends at its highest solid slice; above the next slice the strip is fixture,
    # and so are the stray points around it (stereo noise off the rod's edges).
    top_m = (solid.max() + 2) * guard.slice_m if len(solid) else 0.0
    return (strip | ring) & (along > top_m)


def without_fixture(
    points_W: np.ndarray, lines: Sequence[FixtureLine], guard: FixtureGuard = FixtureGuard()
) -> np.ndarray:
    """Keep mask (N,): False for points on any of the lines' strips (one line per hanging).

    Twice over the lines: another hanging's rod passing near a line looks like surface around
    it until that rod itself is cut."""
    keep = np.ones(len(points_W), bool)
    for line in [*lines, *lines]:
        kept = np.flatnonzero(keep)
        keep[kept[fixture_points(np.asarray(points_W)[kept], line, guard)]] = False
    return keep


def points_on_fixture(
    points_W: np.ndarray,
    true_vertices_W: np.ndarray,
    line: FixtureLine,
    within_m: float = 0.010,
    around_m: float = 0.036,
) -> int:
    """With the true surface known (simulation): how many points lie within `within_m` of the
    fixture's axis and above the object there, i.e. more than `within_m` above the highest
    true surface within `around_m` of the axis (beside a clamp the surface can still rise).
    Every such point is fixture in the model."""
    u = np.asarray(line.u_W, float) / np.linalg.norm(line.u_W)
    p0 = np.asarray(line.p_W, float)

    def along_across(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        along = (np.asarray(p, float) - p0) @ u
        return along, np.linalg.norm(p - p0 - np.outer(along, u), axis=1)

    along_t, across_t = along_across(true_vertices_W)
    near = across_t < around_m
    top = along_t[near].max() if near.any() else 0.0
    along, across = along_across(points_W)
    return int(((across < within_m) & (along > top + within_m)).sum())

"""Pairwise registration as the views arrive: each new view is registered against the earlier
views it overlaps as soon as its cloud is filtered, so that after the last capture only the
pose graph, the hand-eye correction and the surfaces remain.

The pairs are chosen and registered at the poses X_WF @ X_FC of the mount the scan started
with, and the registrations stay in camera frames (X_TS = X_CtCs): a later correction of X_FC
does not invalidate them. `register_views` reuses a pair's registration while its new starting
guess lies within ICP's basin around the registration's answer, and registers it again
otherwise.

The same object runs offline (`scanner reconstruct`), fed the views in the order they were
captured: a scan reconstructed from its files gives the model its streamed run gave.
"""

from __future__ import annotations

import threading
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.transforms import invert
from reconstruction.registration.filtering import FilteredCloud
from reconstruction.registration.pairwise import (
    CloudPyramid,
    IcpConfig,
    PairingView,
    Registration,
    ViewPair,
    build_pyramid,
    correction_at,
    edge_check,
    pairing_view,
    partners_among_earlier,
    register_pair,
)
from reconstruction.registration.views import ViewCloud


@dataclass(frozen=True, eq=False)
class PairIcp:
    """One pair's ICP as run when its later view arrived: the capture indices (source the
    earlier view), how the pair was chosen, the guess ICP started from and its result."""

    source: int
    target: int
    kind: str
    angle_rad: float
    overlap: float
    X_TS_start: np.ndarray
    registration: Registration | None  # None when ICP is off (pairs for the hand-eye fit only)


@dataclass(frozen=True, eq=False)
class _Arrived:
    index: int
    hanging: int
    cloud: FilteredCloud
    X_WC: np.ndarray  # at the mount the pairs are chosen at
    pyramid: CloudPyramid
    pairing: PairingView


class ArrivingPairs:
    """Views added in capture order (`add`); each is paired with earlier views of its hanging
    and, with ICP on, registered against them at once. `add` is called from one thread at a
    time (the view stream's registration thread, or the offline loop)."""

    def __init__(self, icp: IcpConfig, X_FC: np.ndarray) -> None:
        self.icp = icp
        self.X_FC = np.array(X_FC, float)
        self._views: list[_Arrived] = []
        self._pairs: list[PairIcp] = []
        self._lock = threading.Lock()

    def add(self, index: int, hanging: int, cloud: FilteredCloud, X_WF: np.ndarray) -> None:
        pyramid = build_pyramid(cloud, self.icp)
        X_WC = np.asarray(X_WF, float) @ self.X_FC
        new = _Arrived(index, hanging, cloud, X_WC, pyramid, pairing_view(X_WC, pyramid))
        earlier = [v for v in self._views if v.hanging == hanging]
        found = []
        for k, kind, angle, overlap in partners_among_earlier(
            new.pairing, [v.pairing for v in earlier], self.icp
        ):
            other = earlier[k]
            X_TS = invert(X_WC) @ other.X_WC
            registration = (
                register_pair(other.pyramid, pyramid, X_TS, self.icp) if self.icp.enabled else None
            )
            found.append(PairIcp(other.index, index, kind, angle, overlap, X_TS, registration))
        with self._lock:
            self._views.append(new)
            self._pairs += found

    def arrived(self) -> list[tuple[int, int]]:
        """(capture index, hanging) of each view added, in order."""
        with self._lock:
            return [(v.index, v.hanging) for v in self._views]

    def holds(self, index: int, cloud: FilteredCloud) -> bool:
        """Whether `index` arrived with exactly this cloud (not one filtered again since)."""
        with self._lock:
            return any(v.index == index and v.cloud is cloud for v in self._views)

    def pyramid(self, index: int) -> CloudPyramid:
        with self._lock:
            return next(v.pyramid for v in self._views if v.index == index)

    def pairs(self) -> list[PairIcp]:
        with self._lock:
            return list(self._pairs)


def within_basin(
    X_TS_now: np.ndarray, pair: PairIcp, centroid_C: np.ndarray, icp: IcpConfig
) -> bool:
    """Whether ICP started from X_TS_now would end where this pair's ICP ended: the start
    places the source's centroid within `reuse_within_m` of where the result placed it and
    is turned less than `reuse_within_rad` from it (ICP's basin around its answer)."""
    moved_m, turned_rad = correction_at(X_TS_now, pair.registration.X_TS, centroid_C)
    return moved_m <= icp.reuse_within_m and turned_rad <= icp.reuse_within_rad


def arrival_order(stamps_s: Sequence[float], indices: Sequence[int]) -> list[int]:
    """List positions in capture order: by time stamp, views without one (NaN) after those with
    one, ties by capture index."""
    return sorted(
        range(len(indices)),
        key=lambda k: (
            not np.isfinite(stamps_s[k]),
            stamps_s[k] if np.isfinite(stamps_s[k]) else 0.0,
            indices[k],
        ),
    )


def as_view_pairs(pairs: Sequence[PairIcp], position: dict[int, int]) -> list[ViewPair]:
    """The pairs among the views at `position` (capture index -> list position)."""
    return [
        ViewPair(position[p.source], position[p.target], p.kind, p.angle_rad, p.overlap)
        for p in pairs
        if p.source in position and p.target in position
    ]


def arrived_pairs(
    arriving: ArrivingPairs | None,
    views: Sequence[ViewCloud],
    clouds: Sequence[FilteredCloud],
    groups: Sequence[Sequence[int]],
    X_FC: np.ndarray,
    icp: IcpConfig,
) -> ArrivingPairs:
    """`arriving` brought up to every view (list positions grouped by hanging in `groups`) in
    capture order. A new one when `arriving` is None, was made with another X_FC or ICP
    setting, or holds views, hangings or clouds that are not the first ones of that order
    (the streamed views are then not what this run reconstructs). An `arriving` that also
    holds other views (a scan's stream, of which this run takes one hanging) is used as it is
    when it holds all of these, in this order: it is never added to then."""
    indices = [v.index for v in views]
    hanging = {k: h for h, group in enumerate(groups) for k in group}
    expected = [
        (indices[k], hanging[k]) for k in arrival_order([v.stamp_s for v in views], indices)
    ]
    position = {index: k for k, index in enumerate(indices)}
    arrived = [] if arriving is None else arriving.arrived()
    mine = [a for a in arrived if a[0] in position]
    if (
        arriving is None
        or arriving.icp != icp
        or not np.array_equal(arriving.X_FC, X_FC)
        or mine != expected[: len(mine)]
        or (len(mine) < len(arrived) and len(mine) < len(expected))
        or not all(arriving.holds(i, clouds[position[i]]) for i, _ in mine)
    ):
        arriving = ArrivingPairs(icp, X_FC)
        mine = []
    for index, h in expected[len(mine) :]:
        k = position[index]
        arriving.add(index, h, clouds[k], views[k].X_WF)
    return arriving


def share_holding(arriving: ArrivingPairs, among: Collection[int] | None = None) -> float | None:
    """The share of registered pairs (between views `among`, by capture index; None: all) that
    pass their edge checks at the guess they started from (None: none registered): near 1 when
    the mount the pairs started at is within ICP's reach, low when it is far off."""
    done = [
        p
        for p in arriving.pairs()
        if p.registration is not None
        and (among is None or (p.source in among and p.target in among))
    ]
    if not done:
        return None
    holding = sum(
        not edge_check(
            p.registration, p.X_TS_start, arriving.pyramid(p.source).centroid_C, arriving.icp
        )
        for p in done
    )
    return holding / len(done)


def outside_basin(
    arriving: ArrivingPairs,
    kept: set[tuple[int, int]],
    indices: Sequence[int],
    X_WC: Sequence[np.ndarray],
) -> int:
    """How many of the `kept` pairs (capture indices: source, target) would not be reached
    by ICP started from these poses of the views (capture `indices`): `within_basin`."""
    position = {index: k for k, index in enumerate(indices)}
    count = 0
    for p in arriving.pairs():
        if (p.source, p.target) not in kept or p.registration is None:
            continue
        X_TS = invert(X_WC[position[p.target]]) @ X_WC[position[p.source]]
        centroid = arriving.pyramid(p.source).centroid_C
        count += not within_basin(X_TS, p, centroid, arriving.icp)
    return count

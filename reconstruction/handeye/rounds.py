"""Registration and the hand-eye correction, round by round.

They feed each other: ICP starts from X_WF @ X_FC, and the correction of X_FC reads the
registered poses. When a round moves X_FC, ICP ran from stale poses (and the AX = XB check
compares with them), so the views are registered again from the corrected X_FC until it stops
moving, or until from the corrected mount every kept pair would start in ICP's basin (the same
edges, the same correction). A correction that moves the views far (the coarse stage's start,
mostly) also moves the crop and the robot's points, which are placed in W: the views are then
filtered again at the new poses.

    filter_step            the views filtered at one X_FC, grouped by hanging
    register_and_correct   the pairs, the coarse stage when they do not hold, the rounds
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.stage_timer import StageTimer
from reconstruction.handeye.basin import coarse_handeye, displacement_at
from reconstruction.handeye.correction import (
    HandEyeConfig,
    HandEyeResult,
    correct_handeye,
    plausible_correction,
)
from reconstruction.hangings.merge import group_positions
from reconstruction.registration.all_views import RegisteredViews, register_hangings
from reconstruction.registration.filtering import (
    FilterConfig,
    FilteredCloud,
    RemovePoints,
    filter_views,
)
from reconstruction.registration.incremental import (
    ArrivingPairs,
    arrived_pairs,
    outside_basin,
    share_holding,
)
from reconstruction.registration.pairwise import IcpConfig
from reconstruction.registration.posegraph import PoseGraphConfig
from reconstruction.registration.views import ViewCloud


@dataclass(frozen=True, eq=False, kw_only=True)
class CorrectionInputs:
    """What registration and the correction work on.

    views: every captured view (in C, with X_WF); X_FC_nominal: the mount the software
    believes; the stages' settings; min_views: fewer usable views after filtering is an
    error; remove_points: the robot's and cell's points (None: keep all); hangings: the
    capture indices of each pass (None: one); arriving: the pairs registered while the views
    arrived (used when they were made from these clouds and this X_FC)."""

    views: Sequence[ViewCloud]
    X_FC_nominal: np.ndarray
    filter: FilterConfig
    icp: IcpConfig
    pose_graph: PoseGraphConfig
    handeye: HandEyeConfig
    min_views: int
    remove_points: RemovePoints | None = None
    hangings: Sequence[Sequence[int]] | None = None
    arriving: ArrivingPairs | None = None


@dataclass(frozen=True, eq=False)
class FilteredViews:
    """The usable views and their clouds (in C) filtered at `X_FC`, the views skipped (index,
    why), and the list positions of each hanging's views."""

    views: list[ViewCloud]
    clouds: list[FilteredCloud]
    skipped: list[tuple[int, str]]
    groups: list[list[int]]
    X_FC: np.ndarray

    @property
    def indices(self) -> list[int]:
        return [v.index for v in self.views]


@dataclass(frozen=True, eq=False)
class CorrectedViews:
    """The last round: its filtered views, their registration (empty without pairs), the
    correction (None when it did not run), the X_FC it ended at, the views' poses after
    registration (or at the round's start mount without it), and how many pairs were
    registered while the views arrived and used."""

    filtered: FilteredViews
    registered: RegisteredViews
    handeye: HandEyeResult | None
    X_FC: np.ndarray
    X_WC: list[np.ndarray]
    pairs_before: int


def filter_step(
    inputs: CorrectionInputs,
    X_FC: np.ndarray,
    timer: StageTimer,
    filtered: Mapping[int, FilteredCloud] | None = None,
) -> FilteredViews:
    """The views filtered at `X_FC` (`filtered`: clouds already filtered there, reused)."""
    with timer("filter"):
        views, clouds, skipped = filter_views(
            inputs.views, X_FC, inputs.filter, inputs.remove_points, filtered
        )
    if len(views) < inputs.min_views:
        raise ScannerError(
            f"only {len(views)} usable view(s) after filtering, {inputs.min_views} needed "
            f"(skipped: {', '.join(f'{i}: {why}' for i, why in skipped) or 'none'})"
        )
    groups = group_positions(views, inputs.hangings or [[v.index for v in views]])
    return FilteredViews(views, clouds, skipped, groups, X_FC)


def _working_distance_m(clouds: Sequence[FilteredCloud]) -> float:
    return float(np.mean([np.median(c.points_C[:, 2]) for c in clouds if len(c)]))


def _runs_coarse(inputs: CorrectionInputs, first: FilteredViews, holding: float | None) -> bool:
    """The coarse fit runs when the pairs at the nominal mount do not hold (or there are
    none to tell) and there are views enough for it."""
    c = inputs.handeye
    return (
        c.enabled
        and c.coarse.enabled
        and len(first.views) >= 3
        and (holding is None or holding < c.coarse.skip_when_pairs_hold)
    )


def _coarse_start(
    inputs: CorrectionInputs, first: FilteredViews, holding: float | None, timer: StageTimer
):
    """The coarse hand-eye fit (None when it does not run or finds nothing) and the mount the
    rounds start from: its X_FC when plausible, else the nominal one."""
    if not _runs_coarse(inputs, first, holding):
        return None, inputs.X_FC_nominal
    with timer("handeye_coarse"):
        coarse = coarse_handeye(
            first.clouds,
            [v.X_WF for v in first.views],
            first.groups,
            inputs.X_FC_nominal,
            inputs.handeye.coarse,
            inputs.handeye.seed,
        )
    if coarse is not None and plausible_correction(
        coarse.X_FC, inputs.X_FC_nominal, inputs.handeye
    ):
        return coarse, coarse.X_FC
    return coarse, inputs.X_FC_nominal


def register_and_correct(
    inputs: CorrectionInputs, first: FilteredViews, timer: StageTimer
) -> CorrectedViews:
    """Registration and the hand-eye correction from the views `first` filtered at the
    nominal mount (see the module docstring)."""
    pairing = (inputs.icp.enabled or inputs.handeye.enabled) and len(first.views) >= 2
    holding, streamed = None, len(inputs.arriving.pairs()) if inputs.arriving is not None else 0
    arriving = inputs.arriving
    if pairing:
        with timer("icp"):
            # Offline, or views the scan did not stream: pairwise ICP as if they arrived now.
            arriving = arrived_pairs(
                inputs.arriving, first.views, first.clouds, first.groups, first.X_FC, inputs.icp
            )
        holding = share_holding(arriving, {v.index for v in first.views})
        streamed = streamed if arriving is inputs.arriving else 0
    coarse, X_FC_start = _coarse_start(inputs, first, holding, timer)
    current = first
    registered = RegisteredViews((), None, (), ())
    handeye = None
    X_FC = inputs.X_FC_nominal
    X_WC: list[np.ndarray] = []
    for _ in range(max(inputs.handeye.max_rounds, 1)):
        distance_m = _working_distance_m(current.clouds)
        if displacement_at(current.X_FC, X_FC_start, distance_m) > (
            inputs.handeye.coarse.refilter_above_m
        ):
            # The crop and the robot's points are placed in W: redo them at the new poses.
            current = filter_step(inputs, X_FC_start, timer)
            if pairing:
                with timer("icp"):
                    arriving = arrived_pairs(
                        None, current.views, current.clouds, current.groups, X_FC_start, inputs.icp
                    )
        X_WF = [v.X_WF for v in current.views]
        X_WC_start = [X @ X_FC_start for X in X_WF]
        indices = current.indices
        if (inputs.icp.enabled or inputs.handeye.enabled) and len(current.views) >= 2:
            registered = register_hangings(
                X_WC_start,
                indices,
                current.groups,
                inputs.icp,
                inputs.pose_graph,
                timer,
                arriving,
            )
        X_WC = list(registered.X_WC) if registered.X_WC is not None else X_WC_start
        if not (inputs.handeye.enabled and len(current.views) >= 2):
            break
        with timer("handeye"):
            handeye = correct_handeye(
                current.clouds,
                X_WF,
                registered.X_WC,
                registered.pairs,
                inputs.X_FC_nominal,
                inputs.handeye,
                coarse,
                X_FC_start,
            )
        X_FC = handeye.X_FC
        kept = {(indices[e.source], indices[e.target]) for e in registered.kept_edges}
        if displacement_at(X_FC_start, X_FC, distance_m) <= inputs.handeye.round_tolerance_m or (
            inputs.icp.enabled
            and not outside_basin(arriving, kept, indices, [X @ X_FC for X in X_WF])
        ):
            # From the corrected mount ICP would end where it ended on every kept pair: the
            # same edges, the same correction.
            break
        X_FC_start = X_FC
    return CorrectedViews(current, registered, handeye, X_FC, X_WC, streamed)

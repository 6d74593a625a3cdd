"""Putting the hangings of a scan into one frame: each pass's views are registered among
themselves (robot poses, ICP, the shared X_FC); then each further pass is aligned onto the
passes before it (`pass_alignment`), and its camera poses move with it.

The reference frame is the first hanging's: the merged model, and its metrics, are there.

A pass whose alignment does not verify is never merged. A scan's own reconstruction leaves it
out (`leave_out=True`): the model of the passes that aligned is worth keeping, and the report
says which pass failed and why; a merge of separate scans refuses it (another object, or the
wrong scan, must not become half of a model).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.errors import RefusedResultError, ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.evaluation.support import SupportPlane
from reconstruction.hangings.alignment import AlignmentConfig, PassAlignment, align_pass
from reconstruction.hangings.free_space import SeenSpace
from reconstruction.hangings.turntable import KnownTurns
from reconstruction.registration.filtering import FilteredCloud, RemovePoints
from reconstruction.registration.views import ViewCloud
from reconstruction.surfaces.fixture import FixtureLine
from reconstruction.surfaces.fused import fuse_clouds


def group_positions(
    views: Sequence[ViewCloud], hangings: Sequence[Sequence[int]]
) -> list[list[int]]:
    """For each hanging, the list positions of its views among `views`."""
    where = {v.index: k for k, v in enumerate(views)}
    groups = [[where[i] for i in hanging if i in where] for hanging in hangings]
    empty = [h + 1 for h, g in enumerate(groups) if len(g) < 2]
    if empty and len(groups) > 1:
        raise ScannerError(
            f"hanging(s) {', '.join(map(str, empty))}: fewer than 2 usable views; a pass "
            "cannot be aligned without a model of its own"
        )
    return groups


def align_hangings(
    views: Sequence[ViewCloud],
    clouds: Sequence[FilteredCloud],
    X_WC: Sequence[np.ndarray],
    groups: Sequence[Sequence[int]],
    config: AlignmentConfig,
    voxel_m: float,
    leave_out: bool = False,
    turns: KnownTurns | None = None,
    earlier: Mapping[int, PassAlignment] | None = None,
) -> tuple[list[np.ndarray], tuple[PassAlignment, ...]]:
    """Camera poses of every view in the first hanging's frame, and each further hanging's
    alignment. One that does not verify raises RefusedResultError naming the failed checks;
    with `leave_out`, its views keep their own frame instead, it is no reference for the
    hangings after it, and its alignment is returned unverified. `turns`: the passes' known
    turns (a turntable's), each pass's starting guess, about the axis as the verified
    alignments before it calibrate it. `earlier`: by hanging, its verified alignment found on
    the same captures while they were scanned (the quick model's), refined and verified
    instead of searched for again."""
    X_WC = [np.asarray(X) for X in X_WC]
    first = list(groups[0])
    reference = fuse_clouds([clouds[k] for k in first], [X_WC[k] for k in first], voxel_m)
    points, colors = [reference.points_W], [reference.colors]
    seen_depths = [views[k].depth for k in first if views[k].depth is not None]
    seen_poses = [X_WC[k] for k in first if views[k].depth is not None]
    alignments = []
    for hanging, group in enumerate(groups[1:], start=1):
        fused = fuse_clouds([clouds[k] for k in group], [X_WC[k] for k in group], voxel_m)
        seen = SeenSpace(tuple(seen_depths), tuple(seen_poses))
        alignment = align_pass(
            hanging,
            fused.points_W,
            np.vstack(points),
            seen,
            config,
            fused.colors,
            np.vstack(colors),
            start=None if turns is None else turns.start(hanging, verified_turns(alignments)),
            earlier=None if earlier is None else earlier.get(hanging),
        )
        alignments.append(alignment)
        if not alignment.verified:
            if leave_out:
                continue
            raise RefusedResultError(
                f"hanging {hanging + 1} could not be aligned with the hangings before it, no "
                f"model written: {'; '.join(alignment.failures)}"
            )
        for k in group:
            X_WC[k] = alignment.T @ X_WC[k]
            if views[k].depth is not None:
                seen_depths.append(views[k].depth)
                seen_poses.append(X_WC[k])
        points.append(transform_points(alignment.T, fused.points_W))
        colors.append(fused.colors)
    return X_WC, tuple(alignments)


def verified_turns(alignments: Sequence[PassAlignment]) -> list[tuple[int, np.ndarray]]:
    """(pass, T) of the alignments that verified: what calibrates a turntable's axis."""
    return [(a.hanging, a.T) for a in alignments if a.verified]


def left_out(alignments: Sequence[PassAlignment]) -> tuple[int, ...]:
    """The hangings (0-based) whose alignment did not verify: left out of the model."""
    return tuple(a.hanging for a in alignments if not a.verified)


def to_first_frame(alignments: Sequence[PassAlignment]) -> list[np.ndarray | None]:
    """Per hanging (the first one included), the transform of its frame into the first's;
    None for a hanging left out (its alignment did not verify)."""
    return [np.eye(4), *(a.T if a.verified else None for a in alignments)]


@dataclass(frozen=True, eq=False)
class PlacedHangings:
    """The hangings in the first one's frame, ready to be fused.

    X_WC: every view's camera pose (4x4), in the first hanging's frame; a left-out hanging's
    views keep their own frame. alignments: each further hanging's, verified or not. kept: the
    list positions of the views that make the model (all but the left-out hangings'). fixtures:
    the kept hangings' rod lines in the first frame. remove_points: the caller's filter for
    points in the first frame (None: none)."""

    X_WC: list[np.ndarray]
    alignments: tuple[PassAlignment, ...]
    kept: list[int]
    fixtures: list[FixtureLine]
    remove_points: RemovePoints | None


def place_hangings(
    views: Sequence[ViewCloud],
    clouds: Sequence[FilteredCloud],
    X_WC: Sequence[np.ndarray],
    groups: Sequence[Sequence[int]],
    config: AlignmentConfig,
    voxel_m: float,
    fixtures: Sequence[FixtureLine] = (),
    remove_points: RemovePoints | None = None,
    leave_out: bool = False,
    turns: KnownTurns | None = None,
    earlier: Mapping[int, PassAlignment] | None = None,
) -> PlacedHangings:
    """`align_hangings` (when there are several hangings), with what moves with the poses:
    each hanging's rod line (`fixtures`: one for all hangings, or one per hanging, in its own
    frame) and the caller's point filter (`remove_points`, in each view's own frame)."""
    alignments: tuple[PassAlignment, ...] = ()
    if len(groups) > 1:
        X_WC, alignments = align_hangings(
            views, clouds, X_WC, groups, config, voxel_m, leave_out, turns, earlier
        )
    T_of = to_first_frame(alignments)
    moved = []
    if fixtures:
        lines = list(fixtures) * (len(groups) if len(fixtures) == 1 else 1)
        moved = [line.moved(T) for line, T in zip(lines, T_of, strict=True) if T is not None]
    hanging_of = {k: h for h, group in enumerate(groups) for k in group}
    if remove_points is not None and len(groups) > 1:
        remove_points = in_own_frames(
            remove_points, T_of, {v.index: hanging_of[k] for k, v in enumerate(views)}
        )
    left = left_out(alignments)
    kept = [k for k in range(len(views)) if hanging_of[k] not in left]
    return PlacedHangings(list(X_WC), alignments, kept, moved, remove_points)


def in_own_frames(
    remove_points: RemovePoints,
    T_of: Sequence[np.ndarray | None],
    hanging_of: Mapping[int, int],
) -> RemovePoints:
    """The caller's filter for points given in the first hanging's frame: each view's points
    are taken back to its own hanging's frame (T_of[h]: hanging h -> the first; None for a
    hanging left out of the model, whose views are never filtered in the first's frame),
    where its rod and the robot are."""
    inverse = [None if T is None else invert(T) for T in T_of]
    return lambda p_W, index: remove_points(  # noqa: E731
        transform_points(inverse[hanging_of[index]], p_W), index
    )


def placed_supports(
    supports: Sequence[SupportPlane | None],
    groups: Sequence[Sequence[int]],
    alignments,
    views: int,
) -> list[SupportPlane | None] | None:
    """Per view (list position), its hanging's support where the alignment placed that
    hanging (a left-out one's stays in its own frame); None without supports."""
    if not any(s is not None for s in supports):
        return None
    T_of = to_first_frame(alignments)
    out: list[SupportPlane | None] = [None] * views
    for h, group in enumerate(groups):
        support = supports[h] if h < len(supports) else None
        moved = None if support is None or T_of[h] is None else support.moved(T_of[h])
        for k in group:
            out[k] = moved if moved is not None else support
    return out

"""Putting the hangings of a scan into one frame: each pass's views are registered among
themselves (robot poses, ICP, the shared X_FC); then each further pass is aligned onto the
passes before it (`pass_alignment`), and its camera poses move with it.

The reference frame is the first hanging's: the merged model, and its metrics, are there.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from reconstruction.common.errors import RefusedResultError, ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.hangings.alignment import AlignmentConfig, PassAlignment, SeenSpace, align_pass
from reconstruction.registration.filtering import FilteredCloud, RemovePoints
from reconstruction.registration.views import ViewCloud
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
) -> tuple[list[np.ndarray], tuple[PassAlignment, ...]]:
    """Camera poses of every view in the first hanging's frame, and each further hanging's
    verified alignment; RefusedResultError naming the failed checks when one does not verify."""
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
        )
        alignments.append(alignment)
        if not alignment.verified:
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


def to_first_frame(alignments: Sequence[PassAlignment]) -> list[np.ndarray]:
    """Per hanging (the first one included), the transform of its frame into the first's."""
    return [np.eye(4), *(a.T for a in alignments)]


def in_own_frames(
    remove_points: RemovePoints, T_of: Sequence[np.ndarray], hanging_of: Mapping[int, int]
) -> RemovePoints:
    """The caller's filter for points given in the first hanging's frame: each view's points
    are taken back to its own hanging's frame (T_of[h]: hanging h -> the first), where its
    rod and the robot are."""
    inverse = [invert(T) for T in T_of]
    return lambda p_W, index: remove_points(  # noqa: E731
        transform_points(inverse[hanging_of[index]], p_W), index
    )

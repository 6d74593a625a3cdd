"""The orientations of a symmetric object that the alignment's hypotheses did not reach.

A shape with a symmetry (a fluted vase: a turn by one flute about its axis; an ellipsoid: half a
turn) fits the passes before it in each of its symmetric orientations, and the hypothesis
generators (features, rotation grid) land on some of them: which ones, is chance (seen: a vase
whose eight flutes gave fits at 45, 90, 135 and 180 deg from the truth and none at 0). Two fits of
the shape that differ by a turn S reveal the symmetry; the turns about S's axis by multiples of
the nearest whole fraction of a full turn are the other orientations that fit the shape, and only
the texture tells which of them is true."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from reconstruction.common.transforms import invert, make_pose, matrix_to_rotvec, rotation_about


def turn_about_axis(S: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(unit axis, angle in rad, a point on the axis) of the rigid motion S read as a turn
    about a line (its slide along the axis, noise between two fits, is left out)."""
    w = matrix_to_rotvec(S[:3, :3])
    angle = float(np.linalg.norm(w))
    axis = w / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
    # The axis' points c satisfy R c + t = c; (I - R) is singular along the axis: least squares
    # gives the point nearest the origin.
    point = np.linalg.lstsq(np.eye(3) - S[:3, :3], S[:3, 3], rcond=None)[0]
    return axis, angle, point


def sibling_starts(
    fits: Sequence[tuple[float, np.ndarray]],
    distinct_rad: float,
    near: float = 0.8,
    max_turns: int = 12,
) -> list[np.ndarray]:
    """Starts for the orientations symmetric to the best fit of the shape.

    Args:
        fits: (shape score, T) of refined hypotheses (T: the pass's points -> the reference);
            the shape score is the overlap discounted by seen-through space, not the texture.
        distinct_rad: fits turned less than this from the best are the same orientation.
        near: a fit scoring at least this fraction of the best fits the shape as well.
        max_turns: the finest division of a full turn tried (30 deg at 12).

    Returns:
        The best fit turned about the axis of its smallest turn to another fit as good, by each
        multiple of 360 / n deg (n the whole number nearest to 360 deg over that turn) but
        the first; none when no other fit is as good."""
    if not fits:
        return []
    best_score, T_best = max(fits, key=lambda f: f[0])
    turns = []
    for score, T in fits:
        if score < near * best_score:
            continue
        axis, angle, point = turn_about_axis(T @ invert(T_best))
        if angle > distinct_rad:
            turns.append((angle, axis, point))
    if not turns:
        return []
    angle, axis, point = min(turns, key=lambda t: t[0])
    n = min(max(round(2 * math.pi / angle), 2), max_turns)
    starts = []
    for k in range(1, n):
        R = rotation_about(axis, 2 * math.pi * k / n)
        starts.append(make_pose(R, point - R @ point) @ T_best)
    return starts

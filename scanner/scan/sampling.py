"""Spreading points evenly: farthest-point sampling under any distance (viewing directions,
calibration stations); the directions themselves: reconstruction.common.sphere."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def farthest_point_sample(
    count: int, first: int, distances_from: Callable[[int], np.ndarray]
) -> list[int]:
    """Indices of up to `count` items, starting at `first`, each next one the farthest from all
    chosen so far; distances_from(i) gives item i's distance to every item."""
    distance = np.array(distances_from(first), float)
    chosen = [first]
    while len(chosen) < min(count, len(distance)):
        distance[chosen] = -np.inf
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, distances_from(chosen[-1]))
    return chosen

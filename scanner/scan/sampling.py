"""Spreading points evenly: directions on a sphere (Fibonacci lattice) and farthest-point
sampling under any distance (viewing directions, calibration stations)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


def fibonacci_directions(n: int, z_min: float = -1.0, z_max: float = 1.0) -> np.ndarray:
    """(n, 3) unit vectors evenly spread over the sphere zone z_min <= z <= z_max (equal area)."""
    k = np.arange(n) + 0.5
    z = z_max - (z_max - z_min) * k / n
    phi = math.pi * (1 + math.sqrt(5)) * k
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


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

"""Directions spread evenly over the sphere (a Fibonacci lattice): viewing directions, the
directions a hanging may be turned to, the cameras that tell what of a surface is observable."""

from __future__ import annotations

import math

import numpy as np


def fibonacci_directions(n: int, z_min: float = -1.0, z_max: float = 1.0) -> np.ndarray:
    """(n, 3) unit vectors evenly spread over the sphere zone z_min <= z <= z_max (equal area)."""
    k = np.arange(n) + 0.5
    z = z_max - (z_max - z_min) * k / n
    phi = math.pi * (1 + math.sqrt(5)) * k
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

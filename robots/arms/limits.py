"""Whether joint positions lie within an arm's limits (no Drake: the RX60's record uses it too)."""

from __future__ import annotations

import numpy as np


def within_limits(q, lower: np.ndarray, upper: np.ndarray, tol_rad: float = 1e-9) -> bool:
    """Every joint finite and within [lower - tol, upper + tol] (a NaN fails)."""
    q = np.asarray(q, dtype=float)
    return bool(
        np.all(np.isfinite(q)) and np.all(q >= lower - tol_rad) and np.all(q <= upper + tol_rad)
    )

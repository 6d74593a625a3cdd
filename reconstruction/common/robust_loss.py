"""Robust losses, by scipy's names and definitions, for every robust fit in the product.

scipy.optimize.least_squares applies rho(z) to z = (r / scale)^2 (the calibration's refinement
uses it directly). The hand-written Gauss-Newton solvers (pose graph, hand-eye refinement on the
clouds) weight each residual by rho'(z), which is iteratively reweighted least squares on the
same loss, so a loss name means the same thing wherever a configuration gives it.
"""

from __future__ import annotations

import numpy as np

from reconstruction.common.errors import ScannerError

# rho'(z) of scipy's losses, z = (r / scale)^2.
_WEIGHTS = {
    "linear": lambda z: np.ones_like(z),
    "huber": lambda z: np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0))),
    "soft_l1": lambda z: 1.0 / np.sqrt(1.0 + z),
    "cauchy": lambda z: 1.0 / (1.0 + z),
    "arctan": lambda z: 1.0 / (1.0 + z * z),
}
ROBUST_LOSSES = tuple(_WEIGHTS)


def check_loss(name: str, field: str) -> None:
    """ScannerError naming the configuration field when `name` is not a known loss."""
    if name not in _WEIGHTS:
        raise ScannerError(f"{field} '{name}' is not one of {', '.join(ROBUST_LOSSES)}")


def irls_weights(residuals: np.ndarray, loss: str, scale: float) -> np.ndarray:
    """Weight of each residual (same units as `scale`) in a reweighted least-squares step."""
    z = np.square(np.asarray(residuals, float) / scale)
    return _WEIGHTS[loss](z)

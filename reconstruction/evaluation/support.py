"""What holds the object from below (a table's top, a turntable's disc) as an occluder of the
views: the face lying on it, and anything below its top, is hidden from the views of that pass.

The support's top is taken as a plane (a point on it and its upward normal): the views of a
presentation on a support look from above its top (the band of elevations starts there), so
they never see below it, and the face lying on it faces down, away from all of them, but for
the few millimetres of a bridged or noisy surface that a facing test alone would count. Each
pass has its own support (the object is laid or turned anew on it): in a frame other than the
pass's own, the plane moves with the pass (`moved`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# What lies within this of the support's top touches it: the closed surface's bridge over the
# face lying there (Poisson, 1 mm data spacing) stays within a couple of millimetres of it.
CONTACT_M = 0.002


@dataclass(frozen=True, eq=False)
class SupportPlane:
    """The support's top: a point p_W on it and its unit upward normal n_W (metres)."""

    p_W: np.ndarray
    n_W: np.ndarray

    def exposed(self, points_W: np.ndarray, contact_m: float = CONTACT_M) -> np.ndarray:
        """Which points (N, 3) lie more than `contact_m` above the top: the only ones a view
        of this pass can see."""
        return (np.asarray(points_W, float) - self.p_W) @ self.n_W > contact_m

    def moved(self, T: np.ndarray) -> SupportPlane:
        """The same top after the rigid transform T (4x4): in another pass's frame."""
        T = np.asarray(T, float)
        return SupportPlane(T[:3, :3] @ self.p_W + T[:3, 3], T[:3, :3] @ self.n_W)

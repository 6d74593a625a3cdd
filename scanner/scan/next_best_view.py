"""Next-best views: after a hanging's planned views, more views where the model so far leaves
the most surface unseen.

The model so far is the fused cloud of the hanging's captures at their kinematic poses; its
closed (untrimmed Poisson) surface bridges what no view saw. A candidate direction's gain is
the share of that closed surface it would newly see (facing, unoccluded: the coverage
estimate's rule). The best reachable candidate is captured next, until the configured count or
until the best gain drops below the threshold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.evaluation.coverage import seen_surface
from reconstruction.evaluation.metrics import SurfaceSamples, visibility, visible_mask
from reconstruction.surfaces.fused import FusedCloud

# Candidates closer than this to a view already taken add little.
MIN_SEPARATION_RAD = math.radians(10.0)


@dataclass(frozen=True)
class Choice:
    direction: np.ndarray
    gain: float  # share of the closed surface it newly sees


class CoverageModel:
    """The closed surface of the model so far, samples on it, and which of them are seen."""

    def __init__(
        self, fused: FusedCloud, camera_centres_W: Sequence[np.ndarray], samples: int = 20_000
    ) -> None:
        seen = seen_surface(fused, camera_centres_W, samples)
        self.surface, self.samples, self.seen = seen.surface, seen.samples, seen.seen

    @property
    def coverage(self) -> float:
        return float(self.seen.mean())

    def best(
        self,
        center_m: Sequence[float],
        radius_m: float,
        directions: np.ndarray,
        taken: Sequence[np.ndarray],
    ) -> Choice | None:
        """The candidate direction (unit, from the centre) that newly sees the most, among
        those at least MIN_SEPARATION_RAD from every direction already taken."""
        directions = np.asarray(directions, float).reshape(-1, 3)
        if len(taken):
            near = directions @ np.asarray(taken, float).T > math.cos(MIN_SEPARATION_RAD)
            directions = directions[~near.any(axis=1)]
        unseen = ~self.seen
        if not len(directions) or not unseen.any():
            return None
        subset = SurfaceSamples(self.samples.points[unseen], self.samples.normals[unseen])
        cameras = np.asarray(center_m, float) + radius_m * directions
        gains = [row.sum() / len(self.seen) for row in visibility(subset, self.surface, cameras)]
        k = int(np.argmax(gains))
        return Choice(directions[k], float(gains[k]))

    def add(self, camera_centre_W: np.ndarray) -> None:
        self.seen |= visible_mask(self.samples, self.surface, [camera_centre_W])

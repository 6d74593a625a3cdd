"""Where a scan's views go (the `views:` section of a scan configuration); angles in radians,
distances in metres."""

from __future__ import annotations

import math
from dataclasses import dataclass

from reconstruction.common.checks import (
    check_fields,
    fraction,
    integer,
    positive,
    require_choice,
    require_count,
)
from reconstruction.common.errors import ScannerError

DISTRIBUTIONS = ("reachable", "sphere")

# More views than this are a typo (a 24-view scan sees what the arm can reach).
MAX_VIEWS = 1000
# Far beyond the RX60's reach (0.67 m from the shoulder): a typo, not a plan.
MAX_RADIUS_M = 3.0


@dataclass(frozen=True)
class ViewpointConfig:
    """Where the views go. Angles in radians, distances in metres."""

    count: int = integer(24, maximum=MAX_VIEWS)
    radius_m: float = positive(0.5, at_most=MAX_RADIUS_M)
    center_m: tuple[float, float, float] | None = None  # None: the configured object centre
    distribution: str = "reachable"
    elevation_min_rad: float = math.radians(-75.0)
    elevation_max_rad: float = math.radians(75.0)
    candidates: int = 600
    roll_candidates: int = integer(12)
    options_per_view: int = integer(6)
    replace_within_rad: float = positive(math.radians(20.0))
    lloyd_iterations: int = integer(10, minimum=0)
    # Next-best views: after a hanging's planned views, up to this many more, each where the
    # current model's unseen surface is best in view; stop when the best would show less than
    # min_gain of the closed surface.
    max_extra_views: int = integer(0, minimum=0, maximum=MAX_VIEWS)
    min_gain: float = fraction(0.01)

    def __post_init__(self) -> None:
        if self.count < 1:
            raise ScannerError(f"views.count: at least 1 view is needed, got {self.count}")
        check_fields("views", self)
        require_choice("views", "distribution", self.distribution, DISTRIBUTIONS)
        for name in ("elevation_min_rad", "elevation_max_rad"):
            value = getattr(self, name)
            if not -math.pi / 2 <= value <= math.pi / 2:
                raise ScannerError(
                    f"views.{name}: expected an angle in [-pi/2, pi/2], got {value!r}"
                )
        if not self.elevation_min_rad < self.elevation_max_rad:
            raise ScannerError(
                f"views.elevation_min_rad: expected less than views.elevation_max_rad "
                f"({self.elevation_max_rad!r}), got {self.elevation_min_rad!r}"
            )
        require_count("views", self, ("candidates",), minimum=self.count)

"""The planned views as a scan directory records them: each view's index, direction, look-at
viewpoint and its alternative joint configurations."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planners.ik import Viewpoint


@dataclass(frozen=True, eq=False)
class ViewOption:
    """One way to take a view: a camera roll and the joint configuration realising it."""

    roll_rad: float
    q: np.ndarray


@dataclass(frozen=True, eq=False)
class PlannedView:
    """A view to capture: index in the scan, direction from the centre, the look-at viewpoint
    (roll of the preferred option) and the alternative configurations (rolls x IK branches)."""

    index: int
    direction: np.ndarray
    viewpoint: Viewpoint
    options: tuple[ViewOption, ...] = field(default=())

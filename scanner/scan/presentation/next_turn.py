"""The next-best turn of a turntable: the angle whose pass newly sees most of what the passes so
far have not.

The same coverage machinery as the next-best hanging (`scanner.scan.next_hanging`): turning the
object by phi about the vertical through the centre is, for the cameras, turning them by -phi;
a candidate's gain is the share of the closed model's unseen samples the pass's cameras would
see after it. Unlike a re-hang, the turn is exactly what the scanner commands (no yaw to average
over), and it can only turn about the vertical.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.transforms import rotation_about
from reconstruction.evaluation.coverage import SeenSurface
from reconstruction.evaluation.support import SupportPlane
from scanner.scan.next_hanging import UP, unseen_sight

# Candidate turns, 15 deg apart: finer steps change the gain by less than the grid of sight
# directions resolves (8 deg).
CANDIDATES = 24
# A turn within this of an angle a pass already used shows what that pass showed.
MIN_SEPARATION_RAD = math.radians(10.0)


@dataclass(frozen=True)
class TurnChoice:
    """Turn the object by `turn_rad` from where it stands now; `gain`: the expected share of
    the closed model newly seen."""

    turn_rad: float
    gain: float


def wrapped(angle_rad: float) -> float:
    """The angle in (-pi, pi]."""
    return math.pi - (math.pi - angle_rad) % (2 * math.pi)


def next_best_turn(
    seen: SeenSurface,
    centre_W: Sequence[float],
    radius_m: float,
    view_directions: np.ndarray,
    used_turns_rad: Sequence[float] = (0.0,),
    candidates: int = CANDIDATES,
    support: SupportPlane | None = None,
) -> TurnChoice | None:
    """The turn (from now) whose pass (the same view directions, unit, from the centre) newly
    sees the most of `seen`'s unseen samples, away from the turns passes already used
    (`used_turns_rad`, from now: 0 is the pass now); None when nothing is unseen. `support`:
    the disc's top (frame of the pass now; a turn about the vertical keeps it where it is),
    which hides what stands on it from every turn."""
    sight = unseen_sight(seen, centre_W, radius_m)
    if sight is None:
        return None
    d = np.asarray(view_directions, float).reshape(-1, 3)
    # What the sight model says the passes made would see of the "unseen" samples (grazing
    # views, the fixture's shadow, data the filter dropped): another turn only gains what they
    # would not, else a small turn scores the pass it repeats.
    made = np.zeros(len(sight.sees[0]), bool)
    for u in used_turns_rad:
        made |= sight.seen_by(d, rotation_about(UP, u), support)
    best: TurnChoice | None = None
    for k in range(1, candidates):
        turn = wrapped(2 * math.pi * k / candidates)
        if any(abs(wrapped(turn - u)) < MIN_SEPARATION_RAD for u in used_turns_rad):
            continue
        sees = sight.seen_by(d, rotation_about(UP, turn), support)
        gain = float((sees & ~made).sum() / sight.total)
        if best is None or gain > best.gain:
            best = TurnChoice(turn, gain)
    return best

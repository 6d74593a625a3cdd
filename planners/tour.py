"""Visiting order: minimise the total robot motion time over stops with alternative configurations.

An open tour from the current configuration: nearest neighbour, then alternate 2-opt on the
order (configurations fixed) with an exact re-choice of every stop's configuration along the
order (Viterbi over the options), until neither improves. A stop is anything with `options`,
each option a joint configuration `q` (the scan's views: camera rolls x IK branches).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

CostFn = Callable[[np.ndarray, np.ndarray], float]


class _Option(Protocol):
    q: np.ndarray


class TourStop(Protocol):
    """A place to visit, reachable in any of several joint configurations."""

    @property
    def options(self) -> Sequence[_Option]: ...


@dataclass(frozen=True, eq=False)
class Tour:
    """Stops in visiting order with the chosen option index of each; estimated total cost (s)."""

    order: tuple[int, ...]
    option: tuple[int, ...]
    cost_s: float


class _Costs:
    """Cost between (view, option) nodes, computed once."""

    def __init__(self, q_start: np.ndarray, views: Sequence[TourStop], cost: CostFn) -> None:
        self.node_of = [[] for _ in views]
        qs = []
        for v, view in enumerate(views):
            for option in view.options:
                self.node_of[v].append(len(qs))
                qs.append(option.q)
        n = len(qs)
        self.start = np.array([cost(q_start, q) for q in qs])
        self.pair = np.zeros((n, n))
        for i in range(n):
            for j in range(n):
                if i != j:
                    self.pair[i, j] = cost(qs[i], qs[j])

    def node(self, view: int, option: int) -> int:
        return self.node_of[view][option]

    def total(self, order: Sequence[int], option: Sequence[int]) -> float:
        nodes = [self.node(v, option[v]) for v in order]
        return float(self.start[nodes[0]] + sum(self.pair[a, b] for a, b in zip(nodes, nodes[1:])))


def _nearest_neighbour(c: _Costs, n_views: int) -> tuple[list[int], list[int]]:
    order, option = [], [0] * n_views
    left = set(range(n_views))
    current = None
    while left:
        best = None
        for v in left:
            for o, node in enumerate(c.node_of[v]):
                d = c.start[node] if current is None else c.pair[current, node]
                if best is None or d < best[0]:
                    best = (d, v, o, node)
        _, v, o, current = best
        order.append(v)
        option[v] = o
        left.remove(v)
    return order, option


def _two_opt(c: _Costs, order: list[int], option: list[int]) -> bool:
    improved = False
    best = c.total(order, option)
    n = len(order)
    changed = True
    while changed:
        changed = False
        for i in range(n - 1):
            for j in range(i + 1, n):
                candidate = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
                total = c.total(candidate, option)
                if total < best - 1e-9:
                    order[:], best, changed, improved = candidate, total, True, True
    return improved


def _viterbi(c: _Costs, order: list[int], option: list[int]) -> bool:
    """Best option of every view for the fixed order (exact dynamic programme)."""
    nodes = [c.node_of[v] for v in order]
    cost = c.start[nodes[0]].copy()
    back = []
    for prev, cur in zip(nodes, nodes[1:]):
        step = cost[:, None] + c.pair[np.ix_(prev, cur)]
        back.append(np.argmin(step, axis=0))
        cost = step.min(axis=0)
    choice = [int(np.argmin(cost))]
    for b in reversed(back):
        choice.append(int(b[choice[-1]]))
    choice.reverse()
    before = c.total(order, option)
    new = list(option)
    for v, o in zip(order, choice):
        new[v] = o
    if c.total(order, new) < before - 1e-9:
        option[:] = new
        return True
    return False


def plan_tour(
    q_start: np.ndarray, views: Sequence[TourStop], cost: CostFn, max_rounds: int = 5
) -> Tour:
    """The visiting order and the option of every stop that minimise the summed `cost` (e.g.
    the planner's estimated motion time) from q_start; `max_rounds` of 2-opt + Viterbi."""
    if not views:
        return Tour((), (), 0.0)
    c = _Costs(q_start, views, cost)
    order, option = _nearest_neighbour(c, len(views))
    for _ in range(max_rounds):
        if not (_two_opt(c, order, option) | _viterbi(c, order, option)):
            break
    return Tour(tuple(order), tuple(option), c.total(order, option))


def tour_cost(
    q_start: np.ndarray,
    views: Sequence[TourStop],
    order: Sequence[int],
    option: Sequence[int],
    cost: CostFn,
) -> float:
    """Estimated cost of visiting `views` in a given order with given options (for comparisons)."""
    q = q_start
    total = 0.0
    for v in order:
        q_next = views[v].options[option[v]].q
        total += cost(q, q_next)
        q = q_next
    return total

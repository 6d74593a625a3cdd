"""How many threads a SciPy cKDTree query gets: all cores for large queries, one for small.

SciPy runs a query with `workers` != 1 on Python threads started for that call, which a small
query does not repay. Measured on the 2-core machine against a tree of 200,000 points: 1,000
query points cost 0.65 ms of CPU on one thread and 1.06 ms on all (no sooner done); 5,000
points 3.5 ms either way; 20,000 points 16.3 ms on one thread against 8.8 ms of wall time on two
(the same CPU), 200,000 points 146 against 73 ms.
"""

from __future__ import annotations

PARALLEL_FROM_POINTS = 10_000


def query_workers(n_points: int) -> int:
    """The `workers` argument for a query of `n_points` points."""
    return -1 if n_points >= PARALLEL_FROM_POINTS else 1

"""Nearest-neighbour queries: one thread for small queries, all cores for large ones, the same
answers either way."""

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.common.kdtree import PARALLEL_FROM_POINTS, query_workers


def test_small_queries_run_on_one_thread_and_large_ones_on_all():
    assert query_workers(PARALLEL_FROM_POINTS - 1) == 1
    assert query_workers(PARALLEL_FROM_POINTS) == -1
    rng = np.random.default_rng(0)
    tree = cKDTree(rng.random((5000, 3)))
    q = rng.random((PARALLEL_FROM_POINTS, 3))
    one = tree.query(q, distance_upper_bound=0.05, workers=1)
    many = tree.query(q, distance_upper_bound=0.05, workers=query_workers(len(q)))
    np.testing.assert_array_equal(one[0], many[0])
    np.testing.assert_array_equal(one[1], many[1])

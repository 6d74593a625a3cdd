"""Pairwise ICP, pair selection, edge checks and the pose graph, on synthetic data."""

from __future__ import annotations

import math

import numpy as np
import pytest
from synthetic_views import OBJECT_CENTER_W, ROBOT_SIDE, cap_directions, look_at, make_scan

from reconstruction.common.transforms import (
    invert,
    pose_difference,
    transform_points,
    twist_to_pose,
)
from reconstruction.registration.filtering import FilterConfig, RegionOfInterest, filter_view
from reconstruction.registration.pairwise import (
    IcpConfig,
    build_pyramid,
    correction_at,
    edge_check,
    kinematic_X_TS,
    register_pair,
    select_pairs,
)
from reconstruction.registration.posegraph import PoseEdge, PoseGraphConfig, optimise_pose_graph

ROI = RegionOfInterest(center_m=tuple(OBJECT_CENTER_W))


@pytest.fixture(scope="module")
def three_views():
    """Three views 15-30 deg apart of the pebble. Curved everywhere, so ICP is well posed; on the
    bracket's flat faces the in-plane pose rests on the edges, whose sampling (half a pixel
    footprint, 0.4 mm here) biases pairwise ICP by ~0.2 deg even without noise."""
    scan = make_scan("pebble", directions=cap_directions(3, ROBOT_SIDE, math.radians(20.0)))
    clouds = [
        filter_view(v.index, v.points_C, v.colors, X, FilterConfig(roi=ROI))
        for v, X in zip(scan.views, scan.X_WC_true)
    ]
    return scan, clouds, [build_pyramid(c, IcpConfig()) for c in clouds]


def test_icp_recovers_a_known_offset(three_views):
    scan, _, pyramids = three_views
    X_TS_true = invert(scan.X_WC_true[1]) @ scan.X_WC_true[0]
    # Start ~10 mm and 0.6 deg off at the object: what a 3 mm / 1 deg hand-eye error does
    # between two views 20-70 deg apart.
    X_TS_start = twist_to_pose([0.006, -0.007, 0.005, 0.004, -0.003, 0.003]) @ X_TS_true
    start_err = correction_at(X_TS_start, X_TS_true, pyramids[0].centroid_C)
    assert 0.005 < start_err[0] < 0.012
    reg = register_pair(pyramids[0], pyramids[1], X_TS_start, IcpConfig())
    moved_m, turned_rad = correction_at(reg.X_TS, X_TS_true, pyramids[0].centroid_C)
    # 0.3 mm depth noise over ~20k points: the overlap's centroid is pinned to tens of um
    # (measured: 9 um, 0.013 deg).
    assert moved_m < 5e-5
    assert math.degrees(turned_rad) < 0.03
    assert reg.fitness > 0.5 and reg.converged
    assert reg.inlier_rmse_m < 0.001  # two noisy clouds, 0.3 mm each, 1 mm voxels
    assert reg.information.shape == (6, 6) and reg.n_correspondences > 1000


def test_the_information_matrix_is_the_librarys_at_the_final_pose(three_views):
    import open3d as o3d

    scan, _, pyramids = three_views
    X_TS_start = invert(scan.X_WC_true[1]) @ scan.X_WC_true[0]
    config = IcpConfig()
    reg = register_pair(pyramids[0], pyramids[1], X_TS_start, config)
    expected = o3d.pipelines.registration.get_information_matrix_from_point_clouds(
        pyramids[0].levels[-1],
        pyramids[1].levels[-1],
        config.levels[-1].max_correspondence_m,
        reg.X_TS,
    )
    np.testing.assert_allclose(reg.information, np.asarray(expected), rtol=1e-12, atol=1e-12)
    assert reg.information[3, 3] == reg.n_correspondences  # one translation row per match


def test_edges_far_from_the_kinematic_guess_are_pruned(three_views):
    scan, _, pyramids = three_views
    X_TS_true = invert(scan.X_WC_true[1]) @ scan.X_WC_true[0]
    reg = register_pair(pyramids[0], pyramids[1], X_TS_true, IcpConfig())
    assert edge_check(reg, X_TS_true, pyramids[0].centroid_C, IcpConfig()) == ""
    # The same result judged against a guess 30 mm away: ICP "jumped", distrust it.
    far = twist_to_pose([0, 0, 0, 0.03, 0, 0]) @ X_TS_true
    assert "inconsistent" in edge_check(reg, far, pyramids[0].centroid_C, IcpConfig())
    strict = IcpConfig(min_fitness=0.999)
    assert "fitness" in edge_check(reg, X_TS_true, pyramids[0].centroid_C, strict)


def test_pairs_link_neighbours_and_mark_odometry(three_views):
    scan, _, pyramids = three_views
    pairs = select_pairs(scan.X_WC_true, pyramids, IcpConfig())
    assert {(p.source, p.target) for p in pairs} == {(0, 1), (0, 2), (1, 2)}
    kinds = {(p.source, p.target): p.kind for p in pairs}
    assert kinds[(0, 1)] == kinds[(1, 2)] == "odometry" and kinds[(0, 2)] == "loop"
    assert all(p.overlap >= 0.3 for p in pairs)
    narrow = IcpConfig(max_pair_angle_rad=math.radians(1.0))
    assert select_pairs(scan.X_WC_true, pyramids, narrow) == []


# ---- pose graph on exact synthetic measurements (no clouds needed) ----


def _ring(n: int = 12) -> list[np.ndarray]:
    """Cameras all around the object, 0.5 m away, looking at it."""
    X = []
    for k in range(n):
        a = 2 * math.pi * k / n
        d = np.array([math.cos(a), math.sin(a), -0.3])
        X.append(look_at(OBJECT_CENTER_W + 0.5 * d / np.linalg.norm(d), OBJECT_CENTER_W, 0.0))
    return X


def _edge(X_WC: list[np.ndarray], s: int, t: int, X_err=None, kind="loop") -> PoseEdge:
    """An edge as ICP would give it: information of a 0.1 m patch of 2000 points around the
    object centre in the source frame."""
    rng = np.random.default_rng(s * 100 + t)
    p_S = transform_points(invert(X_WC[s]), OBJECT_CENTER_W + 0.05 * rng.standard_normal((2000, 3)))
    X_TS = invert(X_WC[t]) @ X_WC[s]
    if X_err is not None:
        X_TS = X_err @ X_TS
    p_T = transform_points(X_TS, p_S)
    info = np.zeros((6, 6))
    for p in p_T:
        G = np.hstack(
            [-np.array([[0, -p[2], p[1]], [p[2], 0, -p[0]], [-p[1], p[0], 0]]), np.eye(3)]
        )
        info += G.T @ G
    return PoseEdge(s, t, X_TS, info, len(p_T), p_S.mean(axis=0), kind)


@pytest.mark.parametrize("method", ["least_squares", "open3d"])
def test_pose_graph_closes_a_loop(method):
    X_true = _ring()
    n = len(X_true)
    # Odometry that drifts: every step turns 0.05 deg too far about the camera's y axis (close
    # to the ring's axis for every view), so the chained poses are ~0.5 deg off at the end.
    bias = twist_to_pose([0, math.radians(0.05), 0, 0.00005, 0, 0])
    edges = [_edge(X_true, k, k + 1, bias, "odometry") for k in range(n - 1)]
    edges.append(_edge(X_true, n - 1, 0))  # the loop closure, exact
    chained = [X_true[0]]
    for e in edges[:-1]:
        chained.append(chained[-1] @ invert(e.X_TS))
    chain_err = pose_difference(chained[-1], X_true[-1])
    assert math.degrees(chain_err[1]) > 0.4

    result = optimise_pose_graph(X_true, edges, PoseGraphConfig(method=method))
    # Relative poses after the graph: the loop's drift is spread over 12 edges, so no two views
    # disagree by more than a fraction of the chain's end error.
    worst = max(
        pose_difference(invert(result.X_WC[j]) @ result.X_WC[i], invert(X_true[j]) @ X_true[i])[1]
        for i in range(n)
        for j in range(n)
    )
    assert worst < 0.5 * chain_err[1]
    # The loop-closure edge is satisfied to the spread drift, not ignored.
    loop = [r for r in result.residuals if r.kind == "loop"][0]
    assert loop.kept and loop.rotation_rad < chain_err[1] / 4


def test_pose_graph_prunes_a_wrong_edge_and_keeps_the_gauge():
    X_true = _ring()
    n = len(X_true)
    edges = [_edge(X_true, k, (k + 1) % n) for k in range(n)]
    edges += [_edge(X_true, k, (k + 2) % n) for k in range(n)]
    wrong = _edge(X_true, 0, 6, twist_to_pose([0, 0, 0, 0.005, 0, 0]))
    edges.append(wrong)
    # Kinematic priors with independent 2 mm / 0.3 deg errors per view.
    rng = np.random.default_rng(4)
    priors = [
        X
        @ twist_to_pose(
            np.concatenate(
                [math.radians(0.3) * rng.standard_normal(3), 0.002 * rng.standard_normal(3)]
            )
        )
        for X in X_true
    ]
    result = optimise_pose_graph(priors, edges, PoseGraphConfig())
    status = {(r.source, r.target): r.kept for r in result.residuals}
    assert status[(0, 6)] is False
    assert sum(status.values()) == len(edges) - 1
    # Views agree with each other to the exact edges (um), and the set sits where the priors
    # put it on average: its error is ~1/sqrt(12) of a single prior's, not one anchor's.
    rel = max(r.translation_m for r in result.residuals if r.kept)
    assert rel < 2e-5  # edge_sigma_m is 0.3 mm: the priors' pull is far below it
    prior_err = np.mean([pose_difference(p, t)[0] for p, t in zip(priors, X_true)])
    graph_err = np.mean([pose_difference(x, t)[0] for x, t in zip(result.X_WC, X_true)])
    assert graph_err < 0.6 * prior_err


def test_kinematic_guess_is_target_from_source():
    X_WC = _ring(3)
    from reconstruction.registration.pairwise import ViewPair

    X_TS = kinematic_X_TS(X_WC, ViewPair(2, 0, "loop", 0.0, 1.0))
    p_S = np.array([[0.01, 0.02, 0.5]])
    np.testing.assert_allclose(
        transform_points(X_WC[0] @ X_TS, p_S), transform_points(X_WC[2], p_S), atol=1e-12
    )


def test_a_streams_pairs_are_used_for_one_of_its_hangings_and_never_added_to(monkeypatch):
    """A scan's quick model of its first hanging takes the pairs the stream registered while
    the views arrived (which also holds the next hanging's views): no pair registered again,
    the stream's record left as it was; a record without all of the hanging's views is not
    used."""
    import reconstruction.registration.incremental as incremental
    from reconstruction.registration.incremental import ArrivingPairs, arrived_pairs, share_holding

    scan = make_scan("pebble", directions=cap_directions(6, ROBOT_SIDE, math.radians(20.0)))
    clouds = [
        filter_view(v.index, v.points_C, v.colors, X, FilterConfig(roi=ROI))
        for v in scan.views
        for X in [v.X_WF @ scan.X_FC_nominal]
    ]
    icp = IcpConfig()
    stream = ArrivingPairs(icp, scan.X_FC_nominal)
    for k, (view, cloud) in enumerate(zip(scan.views, clouds)):
        stream.add(view.index, 0 if k < 3 else 1, cloud, view.X_WF)
    before = stream.arrived(), stream.pairs()
    first = list(range(3))
    calls = []
    monkeypatch.setattr(incremental, "register_pair", lambda *a: calls.append(a))

    used = arrived_pairs(stream, scan.views[:3], clouds[:3], [first], scan.X_FC_nominal, icp)
    assert used is stream and not calls
    assert stream.arrived() == before[0] and len(stream.pairs()) == len(before[1])
    ours = {v.index for v in scan.views[:3]}
    mine = [p for p in stream.pairs() if p.source in ours and p.target in ours]
    assert mine and len(mine) < len(stream.pairs())  # the second hanging's pairs are there too
    holding = share_holding(stream, ours)
    assert holding == sum(
        not edge_check(p.registration, p.X_TS_start, stream.pyramid(p.source).centroid_C, icp)
        for p in mine
    ) / len(mine)

    # Four views of which the stream holds three, beside others: registered anew.
    monkeypatch.undo()
    views = [*scan.views[:3], scan.views[3]]
    anew = arrived_pairs(stream, views, clouds[:4], [list(range(4))], scan.X_FC_nominal, icp)
    assert anew is not stream and [i for i, _ in anew.arrived()] == [v.index for v in views]
    assert stream.arrived() == before[0]

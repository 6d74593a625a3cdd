"""Pose graph over the views: ICP edges (odometry and loop closures) plus the kinematic prior.

Unknowns are the camera poses X_WC_i. Every ICP edge says X_TS ~ inv(X_WC_t) @ X_WC_s; every
view's kinematic pose X_WF_i @ X_FC is a weak prior. The prior fixes the gauge on average over
all views instead of pinning one anchor view: in a prototype of this pipeline an anchor kept its
own hand-eye error, which made absolute Chamfer worse than no ICP at all (3.2 mm against 1.6 mm
with a 3 mm / 1 deg mount error).

Weights have physical units. An edge's Open3D information matrix (sum over correspondences of
G^T G, G = [-[p]x, I]) divided by its count is the mean of G^T G; scaled by
1/edge_sigma_m^2 it charges a residual transform by how far it moves the overlap's points, in
units of the expected post-ICP misalignment `edge_sigma_m`. The prior charges the camera pose
deviation in units of the kinematic uncertainty.

Methods: "least_squares" (the default: Gauss-Newton, plain least squares first and then IRLS
with a Huber or Cauchy loss per edge, then explicit pruning rounds) and "open3d" (Open3D's
global optimisation with Levenberg-Marquardt and its line process on loop-closure edges, node
0 fixed, then the whole graph moved onto the mean kinematic pose; same pruning rounds after).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from reconstruction.common.checks import (
    check_fields,
    fraction,
    integer,
    non_negative,
    positive,
    require_choice,
)
from reconstruction.common.robust_loss import check_loss, irls_weights
from reconstruction.common.transforms import (
    invert,
    mean_pose,
    pose_difference,
    pose_to_twist,
    skew,
    transform_points,
    twist_to_pose,
)

_reg = o3d.pipelines.registration


@dataclass(frozen=True)
class PoseGraphConfig:
    method: str = "least_squares"
    # Expected misalignment of two views' overlap after ICP: ~the stereo noise (0.2 mm median).
    edge_sigma_m: float = positive(0.0003)
    # Kinematic uncertainty of a camera pose: the hand-eye error (3 mm, 1 deg) dominates.
    prior_translation_sigma_m: float = positive(0.005)
    prior_rotation_sigma_rad: float = positive(math.radians(1.0))
    robust_loss: str = "cauchy"
    robust_scale: float = positive(3.0)  # in sigmas: edges beyond ~3 sigma are down-weighted
    max_iterations: int = integer(20)
    tolerance: float = positive(
        1e-9
    )  # largest step component (rad or m) at which Gauss-Newton stops
    # After optimisation an edge whose residual (at its overlap's centroid) exceeds these is
    # pruned (the worst first) and the graph solved again, at most `max_prune_rounds` times.
    prune_translation_m: float = positive(0.001)
    prune_rotation_rad: float = positive(math.radians(0.2))
    max_prune_rounds: int = integer(10, minimum=0)
    # Open3D method only (see open3d.pipelines.registration.GlobalOptimizationOption).
    open3d_max_correspondence_m: float = positive(0.002)
    open3d_edge_prune_threshold: float = fraction(0.25)
    open3d_preference_loop_closure: float = non_negative(1.0)

    def __post_init__(self) -> None:
        require_choice("pose_graph", "method", self.method, POSE_GRAPH_METHODS)
        check_loss(self.robust_loss, "pose_graph.robust_loss")
        check_fields("pose_graph", self)


@dataclass(frozen=True, eq=False)
class PoseEdge:
    """A relative-pose measurement X_TS between nodes source and target (list positions),
    with Open3D's information matrix and the source cloud's centroid in C_s (for residuals)."""

    source: int
    target: int
    X_TS: np.ndarray
    information: np.ndarray
    n_correspondences: int
    centroid_S: np.ndarray
    kind: str = "loop"


@dataclass(frozen=True)
class EdgeResidual:
    """An edge after the graph: the disagreement between its measurement and the optimised
    poses at its overlap's centroid (m, rad), and whether it was kept."""

    source: int
    target: int
    kind: str
    translation_m: float
    rotation_rad: float
    kept: bool


@dataclass(frozen=True, eq=False)
class PoseGraphResult:
    X_WC: tuple[np.ndarray, ...]
    residuals: tuple[EdgeResidual, ...]
    rounds: int


def edge_residual(X_WC: Sequence[np.ndarray], edge: PoseEdge) -> tuple[float, float]:
    X_TS_graph = invert(X_WC[edge.target]) @ X_WC[edge.source]
    d = transform_points(X_TS_graph, edge.centroid_S[None]) - transform_points(
        edge.X_TS, edge.centroid_S[None]
    )
    return float(np.linalg.norm(d)), pose_difference(X_TS_graph, edge.X_TS)[1]


def _whitener(edge: PoseEdge, sigma_m: float) -> np.ndarray:
    """L^T with L L^T = information / (count * sigma^2), for residuals in (rot, trans) order."""
    info = edge.information / max(edge.n_correspondences, 1) / sigma_m**2
    # A tiny ridge keeps the Cholesky defined for a degenerate overlap (a plane slides freely).
    info = info + 1e-9 * np.trace(info) * np.eye(6)
    return np.linalg.cholesky(info).T


def _left_error(X_pred: np.ndarray, X_meas: np.ndarray) -> np.ndarray:
    """xi with X_pred = twist(xi) @ X_meas: the target-frame perturbation Open3D's
    information matrix is defined for."""
    return pose_to_twist(X_pred @ invert(X_meas))


def _adjoint(X_AB: np.ndarray) -> np.ndarray:
    """6x6 map of a (w, v) perturbation in B to the same motion expressed in A (first order)."""
    R, t = X_AB[:3, :3], X_AB[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = skew(t)[0] @ R
    return Ad


def _solve_least_squares(
    X_prior: Sequence[np.ndarray], edges: Sequence[PoseEdge], config: PoseGraphConfig
) -> list[np.ndarray]:
    """Gauss-Newton with robust edge weights (IRLS). Node i's pose is
    X_prior_i @ twist(xi_i); an edge's residual is the target-frame twist between the graph's
    X_TS and the measured one, whitened by its information. Small problem: a dense solve."""
    n = len(X_prior)
    whiteners = [_whitener(e, config.edge_sigma_m) for e in edges]
    prior_w = np.array(
        [1 / config.prior_rotation_sigma_rad] * 3 + [1 / config.prior_translation_sigma_m] * 3
    )
    X = [np.asarray(Xp, float).copy() for Xp in X_prior]
    # Least squares first, then the robust loss from there: started at the kinematic poses,
    # every edge sits tens of sigmas off (the hand-eye error), and a robust loss would
    # down-weight them all in favour of the priors.
    for loss in dict.fromkeys(("linear", config.robust_loss)):
        for _ in range(config.max_iterations):
            H = np.zeros((6 * n, 6 * n))
            g = np.zeros(6 * n)
            for i in range(n):
                # Prior residual: the twist from the prior to the current pose, in camera frame.
                r = prior_w * pose_to_twist(invert(X_prior[i]) @ X[i])
                sl = slice(6 * i, 6 * i + 6)
                H[sl, sl] += np.diag(prior_w**2)
                g[sl] += prior_w * r
            for e, Lt in zip(edges, whiteners):
                X_TS = invert(X[e.target]) @ X[e.source]
                r = Lt @ _left_error(X_TS, e.X_TS)
                # One weight per edge, from the length of its whitened residual.
                w = float(irls_weights(np.linalg.norm(r), loss, config.robust_scale))
                # X_TS(xi) = twist(-xi_t) @ X_TS @ twist(xi_s): the source's perturbation reaches
                # the target frame through the adjoint of X_TS.
                J_s = Lt @ _adjoint(X_TS)
                J_t = -Lt
                blocks = ((e.source, J_s), (e.target, J_t))
                for a, Ja in blocks:
                    sa = slice(6 * a, 6 * a + 6)
                    g[sa] += w * Ja.T @ r
                    for b, Jb in blocks:
                        H[sa, slice(6 * b, 6 * b + 6)] += w * Ja.T @ Jb
            step = -np.linalg.solve(H, g)
            X = [X[i] @ twist_to_pose(step[6 * i : 6 * i + 6]) for i in range(n)]
            if np.max(np.abs(step)) < config.tolerance:
                break
    return X


def _solve_open3d(
    X_prior: Sequence[np.ndarray], edges: Sequence[PoseEdge], config: PoseGraphConfig
) -> list[np.ndarray]:
    graph = _reg.PoseGraph()
    for X in X_prior:
        graph.nodes.append(_reg.PoseGraphNode(np.asarray(X, float)))
    for e in edges:
        # Open3D's node pose maps node coordinates to the global frame (our X_WC) and its edge
        # transformation maps source into target coordinates (our X_TS).
        graph.edges.append(
            _reg.PoseGraphEdge(e.source, e.target, e.X_TS, e.information, e.kind == "loop")
        )
    option = _reg.GlobalOptimizationOption(
        max_correspondence_distance=config.open3d_max_correspondence_m,
        edge_prune_threshold=config.open3d_edge_prune_threshold,
        preference_loop_closure=config.open3d_preference_loop_closure,
        reference_node=0,
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        _reg.global_optimization(
            graph,
            _reg.GlobalOptimizationLevenbergMarquardt(),
            _reg.GlobalOptimizationConvergenceCriteria(),
            option,
        )
    X_opt = [np.asarray(node.pose).copy() for node in graph.nodes]
    # Move the gauge from node 0 onto the mean kinematic pose.
    X_gauge = mean_pose([X_prior[i] @ invert(X_opt[i]) for i in range(len(X_opt))])
    return [X_gauge @ X for X in X_opt]


POSE_GRAPH_METHODS: dict[
    str, Callable[[Sequence[np.ndarray], Sequence[PoseEdge], PoseGraphConfig], list[np.ndarray]]
] = {"least_squares": _solve_least_squares, "open3d": _solve_open3d}


def _excess(X_WC: Sequence[np.ndarray], edge: PoseEdge, config: PoseGraphConfig) -> float:
    """Residual over the pruning threshold (> 1: prune), the worse of translation and rotation."""
    t, r = edge_residual(X_WC, edge)
    return max(t / config.prune_translation_m, r / config.prune_rotation_rad)


def optimise_pose_graph(
    X_WC_prior: Sequence[np.ndarray], edges: Sequence[PoseEdge], config: PoseGraphConfig
) -> PoseGraphResult:
    """Refined X_WC per node; edges whose residual stays above the pruning thresholds after a
    round are dropped and the graph solved again without them."""
    solve = POSE_GRAPH_METHODS[config.method]
    kept = list(edges)
    rounds = 0
    while True:
        X_WC = solve(X_WC_prior, kept, config) if kept else [np.array(X, float) for X in X_WC_prior]
        rounds += 1
        excess = {id(e): _excess(X_WC, e, config) for e in kept}
        worst = max(kept, key=lambda e: excess[id(e)], default=None)
        if worst is None or excess[id(worst)] <= 1.0 or rounds > config.max_prune_rounds:
            break
        # Only the worst edge goes per round: one wrong edge drags its neighbours' residuals
        # up too, and they are fine once it is gone.
        kept.remove(worst)
    kept_ids = {id(e) for e in kept}
    residuals = tuple(
        EdgeResidual(e.source, e.target, e.kind, *edge_residual(X_WC, e), id(e) in kept_ids)
        for e in edges
    )
    return PoseGraphResult(tuple(X_WC), residuals, rounds)

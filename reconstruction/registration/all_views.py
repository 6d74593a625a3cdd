"""Registering the views of a scan among themselves: overlapping pairs, pairwise ICP with edge
checks, and the pose graph, within each hanging (views of different hangings saw the object in
different places, so they are never paired)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from reconstruction.common.stage_timer import StageTimer
from reconstruction.registration.incremental import ArrivingPairs, as_view_pairs, within_basin
from reconstruction.registration.pairwise import (
    IcpConfig,
    edge_check,
    kinematic_X_TS,
    register_pair,
)
from reconstruction.registration.posegraph import PoseEdge, PoseGraphConfig, optimise_pose_graph


@dataclass(frozen=True)
class EdgeReport:
    """An ICP pair (capture indices), its registration quality, and the pose graph's residual
    at the overlap (NaN when the edge was pruned before the graph). `status` is 'kept' or
    'pruned: <reason>'."""

    source: int
    target: int
    kind: str
    angle_rad: float
    overlap: float
    fitness: float
    inlier_rmse_m: float
    converged: bool
    status: str
    residual_translation_m: float
    residual_rotation_rad: float


@dataclass(frozen=True, eq=False)
class RegisteredViews:
    """The registration stage's output: overlapping pairs (list positions), the pose graph's
    camera poses (None when ICP is off), the graph's edges and the per-edge report."""

    pairs: tuple[tuple[int, int], ...]
    X_WC: tuple[np.ndarray, ...] | None
    kept_edges: tuple[PoseEdge, ...]
    report: tuple[EdgeReport, ...]


def register_views(
    X_WC_start: Sequence[np.ndarray],
    indices: Sequence[int],
    icp: IcpConfig,
    pose_graph: PoseGraphConfig,
    timer: StageTimer,
    arriving: ArrivingPairs,
) -> RegisteredViews:
    """The pairs `arriving` chose among these views (capture `indices`), their registrations
    (reused while the start X_WC_start puts them within ICP's basin of where they started,
    else ICP again), edge checks and the pose graph. With ICP off, only the overlapping pairs
    (for the hand-eye refinement)."""
    position = {index: k for k, index in enumerate(indices)}
    chosen = [p for p in arriving.pairs() if p.source in position and p.target in position]
    candidates = as_view_pairs(chosen, position)
    pairs = tuple((p.source, p.target) for p in candidates)
    if not icp.enabled or not candidates:
        return RegisteredViews(pairs, None, (), ())

    registrations, edges = [], []
    with timer("icp"):
        for p, done in zip(candidates, chosen):
            source, target = arriving.pyramid(done.source), arriving.pyramid(done.target)
            prior = kinematic_X_TS(X_WC_start, p)
            if done.registration is not None and within_basin(prior, done, source.centroid_C, icp):
                reg = done.registration
            else:
                reg = register_pair(source, target, prior, icp)
            why = edge_check(reg, prior, source.centroid_C, icp)
            registrations.append((p, reg, why))
            if not why:
                edges.append(
                    PoseEdge(
                        p.source,
                        p.target,
                        reg.X_TS,
                        reg.information,
                        reg.n_correspondences,
                        source.centroid_C,
                        p.kind,
                    )
                )
    with timer("pose_graph"):
        graph = optimise_pose_graph(X_WC_start, edges, pose_graph)
    residual = {(r.source, r.target): r for r in graph.residuals}
    report = []
    for p, reg, why in registrations:
        r = residual.get((p.source, p.target))
        status = "pruned: " + why if why else ("kept" if r.kept else "pruned: graph residual")
        report.append(
            EdgeReport(
                indices[p.source],
                indices[p.target],
                p.kind,
                p.angle_rad,
                p.overlap,
                reg.fitness,
                reg.inlier_rmse_m,
                reg.converged,
                status,
                r.translation_m if r else math.nan,
                r.rotation_rad if r else math.nan,
            )
        )
    # graph.residuals follow the order of `edges`.
    kept = tuple(e for e, r in zip(edges, graph.residuals) if r.kept)
    # The hand-eye refinement trusts exactly the overlaps the graph kept.
    return RegisteredViews(
        tuple((e.source, e.target) for e in kept), graph.X_WC, kept, tuple(report)
    )


def register_hangings(
    X_WC_kinematic: Sequence[np.ndarray],
    indices: Sequence[int],
    groups: Sequence[Sequence[int]],
    icp: IcpConfig,
    pose_graph: PoseGraphConfig,
    timer: StageTimer,
    arriving: ArrivingPairs,
) -> RegisteredViews:
    """`register_views` within each hanging (views of different hangings saw the object in
    different places, so they are never paired), combined over all views."""
    if len(groups) == 1:
        return register_views(X_WC_kinematic, indices, icp, pose_graph, timer, arriving)
    pairs, edges, report = [], [], []
    X_WC = list(X_WC_kinematic)
    for group in groups:
        part = register_views(
            [X_WC_kinematic[k] for k in group],
            [indices[k] for k in group],
            icp,
            pose_graph,
            timer,
            arriving,
        )
        pairs += [(group[a], group[b]) for a, b in part.pairs]
        edges += [
            replace(e, source=group[e.source], target=group[e.target]) for e in part.kept_edges
        ]
        report += part.report
        for k, pose in zip(group, part.X_WC or ()):
            X_WC[k] = pose  # a hanging without overlapping pairs keeps its kinematic poses
    return RegisteredViews(
        tuple(pairs), tuple(X_WC) if icp.enabled else None, tuple(edges), tuple(report)
    )

"""From posed view clouds to a fused cloud and meshes: one entry point on in-memory data.

    filter (per view, in C)  ->  register: ICP pairs + pose graph        (icp.enabled)
      ->  hand-eye: AX = XB on the graph's poses, joint X_FC refinement  (handeye.enabled)
      ->  final poses  ->  fused cloud  ->  surfaces (Poisson / TSDF / ball pivoting)

The three variants the benchmark compares are the two flags: `pose_only` (neither), `icp`
(registration only), `corrected` (both; the final poses are X_WF_i @ X_FC_corrected, optionally
polished by one more pose graph with those as priors). One corrected run holds all three pose
sets (`ViewResult.X_WC_kinematic`, `.X_WC_registered`, `.X_WC`) and the filtered clouds, so
`build_surfaces` can mesh each variant without filtering and registering again.

The stages are public (`filter_views`, `register_views`, `correct_handeye`, `build_surfaces`)
for a caller that writes files between them. No file I/O here: `save_outputs` writes files
when asked, and `summary` gives a plain record for a report.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from reconstruction.errors import ScannerError
from reconstruction.filtering import (
    FilterConfig,
    FilterCounts,
    FilteredCloud,
    RemovePoints,
    filter_view,
)
from reconstruction.handeye import HandEyeConfig, HandEyeResult, correct_handeye
from reconstruction.posegraph import PoseEdge, PoseGraphConfig, optimise_pose_graph
from reconstruction.poses import check_pose, pose_difference
from reconstruction.registration import (
    IcpConfig,
    build_pyramid,
    edge_check,
    kinematic_X_TS,
    register_pair,
    select_pairs,
)
from reconstruction.surfaces import (
    DepthView,
    FusedCloud,
    SurfaceConfig,
    SurfaceMesh,
    build_surface,
    fuse_clouds,
    mesh_quality,
    save_cloud,
    save_mesh,
)
from reconstruction.views import ViewCloud


@dataclass(frozen=True)
class ReconstructionConfig:
    filter: FilterConfig = field(default_factory=FilterConfig)
    icp: IcpConfig = field(default_factory=IcpConfig)
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    handeye: HandEyeConfig = field(default_factory=HandEyeConfig)
    surfaces: SurfaceConfig = field(default_factory=SurfaceConfig)
    # After the hand-eye correction, one more pose graph with the corrected kinematic poses as
    # priors and the same ICP edges, to absorb per-view errors (joint offsets) that no shared
    # X_FC can explain.
    final_pose_graph: bool = False
    min_views: int = 2

    def __post_init__(self) -> None:
        if self.min_views < 1:
            raise ScannerError("reconstruction.min_views: must be >= 1")


def _pose_only(c: ReconstructionConfig) -> ReconstructionConfig:
    return replace(c, icp=replace(c.icp, enabled=False), handeye=replace(c.handeye, enabled=False))


def _icp_only(c: ReconstructionConfig) -> ReconstructionConfig:
    return replace(c, icp=replace(c.icp, enabled=True), handeye=replace(c.handeye, enabled=False))


def _corrected(c: ReconstructionConfig) -> ReconstructionConfig:
    return replace(c, icp=replace(c.icp, enabled=True), handeye=replace(c.handeye, enabled=True))


VARIANTS: dict[str, Callable[[ReconstructionConfig], ReconstructionConfig]] = {
    "pose_only": _pose_only,
    "icp": _icp_only,
    "corrected": _corrected,
}


def variant_config(config: ReconstructionConfig, variant: str) -> ReconstructionConfig:
    """The configuration with the ICP / correction flags of a named variant."""
    if variant not in VARIANTS:
        raise ScannerError(f"unknown variant '{variant}'; valid: {', '.join(VARIANTS)}")
    return VARIANTS[variant](config)


@dataclass(frozen=True, eq=False)
class ViewResult:
    """One view's poses: kinematic (nominal X_FC), after the pose graph (None without ICP),
    and the final one the outputs use."""

    index: int
    counts: FilterCounts
    X_WC_kinematic: np.ndarray
    X_WC_registered: np.ndarray | None
    X_WC: np.ndarray


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
class ReconstructionResult:
    views: tuple[ViewResult, ...]
    edges: tuple[EdgeReport, ...]
    X_FC_nominal: np.ndarray
    X_FC: np.ndarray  # the hand-eye transform behind the final poses
    handeye: HandEyeResult | None
    fused: FusedCloud
    meshes: dict[str, SurfaceMesh]
    timings_s: dict[str, float]
    skipped_views: tuple[tuple[int, str], ...]
    notes: tuple[str, ...]
    clouds: tuple[FilteredCloud, ...]  # per kept view, in C (for `build_surfaces`)


@contextmanager
def _timed(timings: dict[str, float], stage: str):
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - t0


def filter_views(
    views: Sequence[ViewCloud],
    X_FC_nominal: np.ndarray,
    config: ReconstructionConfig,
    remove_points: RemovePoints | None = None,
) -> tuple[list[ViewCloud], list[FilteredCloud], list[tuple[int, str]]]:
    """Filter every view at its kinematic pose; views left with too few points are skipped
    (reported), never fatal. Returns the kept views, their clouds, and (index, reason) skips."""
    kept_views, clouds, skipped = [], [], []
    for view in views:
        cloud = filter_view(
            view.index,
            view.points_C,
            view.colors,
            view.X_WF @ X_FC_nominal,
            config.filter,
            remove_points,
        )
        if len(cloud) < config.filter.min_points:
            skipped.append((view.index, f"{len(cloud)} points after filtering"))
            continue
        kept_views.append(view)
        clouds.append(cloud)
    return kept_views, clouds, skipped


@dataclass(frozen=True, eq=False)
class RegisteredViews:
    """The registration stage's output: overlapping pairs (list positions), the pose graph's
    camera poses (None when ICP is off), the graph's edges and the per-edge report."""

    pairs: tuple[tuple[int, int], ...]
    X_WC: tuple[np.ndarray, ...] | None
    kept_edges: tuple[PoseEdge, ...]
    report: tuple[EdgeReport, ...]


def register_views(
    clouds: Sequence[FilteredCloud],
    X_WC_kinematic: Sequence[np.ndarray],
    indices: Sequence[int],
    config: ReconstructionConfig,
    timings: dict[str, float],
) -> RegisteredViews:
    """Pair selection, pairwise ICP with edge checks, and the pose graph. With ICP off, only
    the overlapping pairs (for the hand-eye refinement)."""
    with _timed(timings, "pairs"):
        pyramids = [build_pyramid(c, config.icp) for c in clouds]
        candidates = select_pairs(X_WC_kinematic, pyramids, config.icp)
    pairs = tuple((p.source, p.target) for p in candidates)
    if not config.icp.enabled or not candidates:
        return RegisteredViews(pairs, None, (), ())

    registrations, edges = [], []
    with _timed(timings, "icp"):
        for p in candidates:
            prior = kinematic_X_TS(X_WC_kinematic, p)
            reg = register_pair(pyramids[p.source], pyramids[p.target], prior, config.icp)
            why = edge_check(reg, prior, pyramids[p.source].centroid_C, config.icp)
            registrations.append((p, reg, why))
            if not why:
                centroid = pyramids[p.source].centroid_C
                edges.append(
                    PoseEdge(
                        p.source,
                        p.target,
                        reg.X_TS,
                        reg.information,
                        reg.n_correspondences,
                        centroid,
                        p.kind,
                    )
                )
    with _timed(timings, "pose_graph"):
        graph = optimise_pose_graph(X_WC_kinematic, edges, config.pose_graph)
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


def build_surfaces(
    views: Sequence[ViewCloud],
    clouds: Sequence[FilteredCloud],
    X_WC: Sequence[np.ndarray],
    config: ReconstructionConfig,
    remove_points: RemovePoints | None = None,
    timings: dict[str, float] | None = None,
) -> tuple[FusedCloud, dict[str, SurfaceMesh], list[str]]:
    """Fused cloud and the configured meshes for one set of camera poses. Also what a
    benchmark calls with the other pose sets of a result (kinematic, registered) to compare
    variants without re-running registration. Returns (fused, meshes by method, notes)."""
    timings = {} if timings is None else timings
    notes = []
    with _timed(timings, "fuse"):
        fused = fuse_clouds(clouds, X_WC, config.surfaces.fused_voxel_size_m)
    depth_views = [
        DepthView(v.depth, X, v.index) for v, X in zip(views, X_WC) if v.depth is not None
    ]
    methods = list(config.surfaces.methods)
    if "tsdf" in methods and not depth_views:
        notes.append("TSDF skipped: the views carry no depth maps")
        methods.remove("tsdf")

    def build(method: str) -> SurfaceMesh:
        with _timed(timings, method):
            return build_surface(
                method, fused, config.surfaces, depth_views, config.filter.roi, remove_points
            )

    # Open3D releases the GIL: the (single-threaded, for determinism) Poisson solve runs on one
    # core while TSDF fusion runs on the other.
    with ThreadPoolExecutor(max_workers=max(1, len(methods))) as pool:
        built = list(pool.map(build, methods))
    return fused, dict(zip(methods, built, strict=True)), notes


def reconstruct_views(
    views: Sequence[ViewCloud],
    X_FC_nominal: np.ndarray,
    config: ReconstructionConfig = ReconstructionConfig(),
    remove_points: RemovePoints | None = None,
) -> ReconstructionResult:
    """The whole reconstruction on in-memory views (see the module docstring)."""
    X_FC_nominal = check_pose(X_FC_nominal, "X_FC_nominal")
    indices = [v.index for v in views]
    if len(set(indices)) != len(indices):
        raise ScannerError("views: capture indices must be unique")
    timings: dict[str, float] = {}
    notes: list[str] = []

    with _timed(timings, "filter"):
        views, clouds, skipped = filter_views(views, X_FC_nominal, config, remove_points)
    if len(views) < config.min_views:
        raise ScannerError(
            f"only {len(views)} usable view(s) after filtering, {config.min_views} needed "
            f"(skipped: {', '.join(f'{i}: {why}' for i, why in skipped) or 'none'})"
        )
    X_WF = [v.X_WF for v in views]
    X_WC_kin = [X @ X_FC_nominal for X in X_WF]

    registered = RegisteredViews((), None, (), ())
    if (config.icp.enabled or config.handeye.enabled) and len(views) >= 2:
        registered = register_views(clouds, X_WC_kin, [v.index for v in views], config, timings)
        if not registered.pairs:
            notes.append("no overlapping view pairs: registration and correction skipped")

    handeye = None
    X_FC = X_FC_nominal
    X_WC = list(registered.X_WC) if registered.X_WC is not None else X_WC_kin
    if config.handeye.enabled and len(views) >= 2:
        with _timed(timings, "handeye"):
            handeye = correct_handeye(
                clouds, X_WF, registered.X_WC, registered.pairs, X_FC_nominal, config.handeye
            )
        X_FC = handeye.X_FC
        notes += handeye.notes
        X_WC = [X @ X_FC for X in X_WF]
        if config.final_pose_graph and registered.kept_edges:
            with _timed(timings, "pose_graph"):
                graph = optimise_pose_graph(X_WC, registered.kept_edges, config.pose_graph)
            X_WC = list(graph.X_WC)

    fused, meshes, surface_notes = build_surfaces(
        views, clouds, X_WC, config, remove_points, timings
    )
    notes += surface_notes
    view_results = tuple(
        ViewResult(
            v.index,
            c.counts,
            X_WC_kin[k],
            None if registered.X_WC is None else registered.X_WC[k],
            X_WC[k],
        )
        for k, (v, c) in enumerate(zip(views, clouds))
    )
    return ReconstructionResult(
        view_results,
        registered.report,
        X_FC_nominal,
        X_FC,
        handeye,
        fused,
        meshes,
        timings,
        tuple(skipped),
        tuple(notes),
        tuple(clouds),
    )


def _quality_record(quality, longest: int = 10) -> dict:
    """Mesh topology for the report; only the longest boundary loops (the rim, big holes)."""
    record = dict(vars(quality))
    loops = record.pop("boundary_loops_m")
    record["boundary_loops"] = len(loops)
    record["longest_boundary_loops_m"] = list(loops[:longest])
    return record


def summary(result: ReconstructionResult) -> dict:
    """A plain, YAML/JSON-ready record of the result (SI units; matrices as nested lists)."""
    he = result.handeye
    dt, dr = pose_difference(result.X_FC_nominal, result.X_FC)
    out: dict = {
        "views": [
            {
                "index": v.index,
                "points": v.counts.after_outliers,
                "X_WC": v.X_WC.tolist(),
                "X_WC_kinematic": v.X_WC_kinematic.tolist(),
            }
            for v in result.views
        ],
        "skipped_views": [{"index": i, "reason": why} for i, why in result.skipped_views],
        "edges": [
            {
                "source": e.source,
                "target": e.target,
                "kind": e.kind,
                "fitness": e.fitness,
                "inlier_rmse_m": e.inlier_rmse_m,
                "status": e.status,
                "residual_translation_m": e.residual_translation_m,
                "residual_rotation_rad": e.residual_rotation_rad,
            }
            for e in result.edges
        ],
        "X_FC_nominal": result.X_FC_nominal.tolist(),
        "X_FC": result.X_FC.tolist(),
        "X_FC_change_translation_m": dt,
        "X_FC_change_rotation_rad": dr,
        "fused_points": len(result.fused),
        "meshes": {name: _quality_record(mesh_quality(m)) for name, m in result.meshes.items()},
        "timings_s": result.timings_s,
        "notes": list(result.notes),
    }
    if he is not None:
        out["handeye"] = {
            "source": he.source,
            "axxb": {
                name: {
                    "X_FC": s.X_FC.tolist(),
                    "rms_translation_m": s.rms_translation_m,
                    "rms_rotation_rad": s.rms_rotation_rad,
                    "rejected_views": list(s.rejected_views),
                    "error": s.error,
                }
                for name, s in he.axxb.items()
            },
        }
        if he.refinement is not None:
            r = he.refinement
            out["handeye"]["refinement"] = {
                "rms_before_m": r.rms_before_m,
                "rms_after_m": r.rms_after_m,
                "matches": r.n_matches,
                "iterations": r.iterations,
                "converged": r.converged,
                "formal_std": r.formal_std.tolist(),
                "weakest_mode": r.weakest_mode.tolist(),
                "weakest_sensitivity": r.weakest_sensitivity,
            }
    return out


def save_outputs(
    result: ReconstructionResult, directory: Path, mesh_suffixes: Sequence[str] = (".ply",)
) -> dict[str, Path]:
    """Write fused_cloud.ply and mesh_<method><suffix> for each mesh and suffix; returns the
    paths by name."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = {"fused_cloud": directory / "fused_cloud.ply"}
    save_cloud(result.fused, paths["fused_cloud"])
    for name, mesh in result.meshes.items():
        for suffix in mesh_suffixes:
            path = directory / f"mesh_{name}{suffix}"
            save_mesh(mesh, path)
            paths[f"mesh_{name}{suffix}"] = path
    return paths

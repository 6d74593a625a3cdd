"""From posed view clouds to a fused cloud and meshes: one entry point on in-memory data.

    filter (per view, in C)  ->  register: ICP pairs + pose graph        (icp.enabled)
      ->  hand-eye: AX = XB on the graph's poses, joint X_FC refinement  (handeye.enabled)
      ->  final poses  ->  fused cloud  ->  surfaces (Poisson / TSDF / ball pivoting)

The ICP pairs are registered in capture order (`registration.incremental`): a scan does it
while its views arrive and hands them over (`arriving`); here the views it did not.

The three variants the benchmark compares are the two flags: `pose_only` (neither), `icp`
(registration only), `corrected` (both; the final poses are X_WF_i @ X_FC_corrected, optionally
polished by one more pose graph with those as priors). One corrected run holds all three pose
sets (`ViewResult.X_WC_kinematic`, `.X_WC_registered`, `.X_WC`) and the filtered clouds, so
`build_surfaces` can mesh each variant without filtering and registering again.

The stages are public (`registration.filtering.filter_views`, `registration.all_views.
register_views`, `correct_handeye`, `build_surfaces`) for a caller that writes files between
them. No file I/O here: `reconstruction.outputs` writes the files and the plain record of a
result.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, field, replace

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.stage_timer import StageListener, StageTimer
from reconstruction.common.transforms import check_pose
from reconstruction.evaluation.coverage import Coverage, coverage_estimate
from reconstruction.handeye.basin import coarse_handeye, displacement_at
from reconstruction.handeye.correction import (
    HandEyeConfig,
    HandEyeResult,
    correct_handeye,
    plausible_correction,
)
from reconstruction.hangings.alignment import AlignmentConfig, PassAlignment
from reconstruction.hangings.merge import group_positions, left_out, place_hangings
from reconstruction.registration.all_views import EdgeReport, RegisteredViews, register_hangings
from reconstruction.registration.filtering import (
    FilterConfig,
    FilterCounts,
    FilteredCloud,
    RemovePoints,
    filter_views,
    refiltered,
)
from reconstruction.registration.incremental import (
    ArrivingPairs,
    arrived_pairs,
    outside_basin,
    share_holding,
)
from reconstruction.registration.pairwise import IcpConfig
from reconstruction.registration.posegraph import PoseGraphConfig, optimise_pose_graph
from reconstruction.registration.views import ViewCloud
from reconstruction.surfaces.build import surface_from
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.fixture import FixtureLine, without_fixture
from reconstruction.surfaces.fused import FusedCloud, fuse_clouds, refine_fused
from reconstruction.surfaces.meshes import DepthView, SurfaceInput, SurfaceMesh
from reconstruction.surfaces.poisson_solver import start_solver


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
    # Putting the passes of a multi-hanging scan into one frame.
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)

    def __post_init__(self) -> None:
        if self.min_views < 1:
            raise ScannerError(f"reconstruction.min_views: must be >= 1, got {self.min_views}")


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
    """One view's poses: kinematic (nominal X_FC, its hanging's frame), after the last round's
    pose graph (None without ICP; started at that round's mount), and the final one used."""

    index: int
    counts: FilterCounts
    X_WC_kinematic: np.ndarray
    X_WC_registered: np.ndarray | None
    X_WC: np.ndarray  # in the first hanging's frame
    hanging: int = 0


@dataclass(frozen=True, eq=False, kw_only=True)
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
    alignments: tuple[PassAlignment, ...] = ()  # hangings 2, 3, ... onto the first
    # The fused cloud at the nominal X_FC, kept when the correction did not converge.
    fused_nominal: FusedCloud | None = None
    # How much of the object the views saw (no truth), all of them and per hanging; made
    # when the caller tells where each view's cameras were (`reconstruct_views(eyes_of=)`).
    coverage: Coverage | None = None
    hanging_coverage: tuple[Coverage, ...] = ()
    # Pairs registered before the reconstruction began (as the views arrived) and used.
    pairs_before: int = 0

    @property
    def left_out(self) -> tuple[int, ...]:
        """The hangings (0-based) left out of the model: their alignment did not verify."""
        return left_out(self.alignments)


def build_surfaces(
    views: Sequence[ViewCloud],
    clouds: Sequence[FilteredCloud],
    X_WC: Sequence[np.ndarray],
    config: ReconstructionConfig,
    remove_points: RemovePoints | None = None,
    timer: StageTimer | None = None,
    beside: Callable[[FusedCloud], None] | None = None,
    fixtures: Sequence[FixtureLine] = (),
) -> tuple[FusedCloud, dict[str, SurfaceMesh], list[str]]:
    """Fused cloud and the configured meshes for one set of camera poses. Also what a
    benchmark calls with the other pose sets of a result (kinematic, registered) to compare
    variants without re-running registration. Returns (fused, meshes by method, notes).
    `beside(fused)`: more work on the fused cloud, done while the meshes are built.
    `fixtures`: the lines of the rods the object hung from, in the frame of `X_WC`: a thin
    strip left along one is cut from the fused cloud before meshing."""
    timer = timer or StageTimer()
    notes = []
    with timer("fuse"):
        fused = fuse_clouds(clouds, X_WC, config.surfaces.fused_voxel_size_m)
        surfaces = config.surfaces
        fused = refine_fused(fused, surfaces.fused_normal_radius_m, surfaces.fused_outlier_sigmas)
        if fixtures:
            keep = without_fixture(fused.points_W, fixtures)
            if not keep.all():
                notes.append(f"{int((~keep).sum())} fused points on the fixture's line cut")
                fused = FusedCloud(fused.points_W[keep], fused.colors[keep], fused.normals_W[keep])
    depth_views = [
        DepthView(v.depth, X, v.index) for v, X in zip(views, X_WC) if v.depth is not None
    ]
    methods = list(config.surfaces.methods)
    if "tsdf" in methods and not depth_views:
        notes.append("TSDF skipped: the views carry no depth maps")
        methods.remove("tsdf")

    inputs = SurfaceInput(fused, depth_views, config.filter.roi, remove_points)

    def build(method: str) -> SurfaceMesh:
        with timer(method):
            return surface_from(method, inputs, config.surfaces)

    # The (single-threaded, for determinism) Poisson solve runs in a process of its own, TSDF
    # fusion and `beside` share the other core.
    with ThreadPoolExecutor(max_workers=len(methods) + 1) as pool:
        also = pool.submit(beside, fused) if beside is not None else None
        built = list(pool.map(build, methods))
        if also is not None:
            also.result()
    return fused, dict(zip(methods, built, strict=True)), notes


def reconstruct_views(
    views: Sequence[ViewCloud],
    X_FC_nominal: np.ndarray,
    config: ReconstructionConfig = ReconstructionConfig(),
    remove_points: RemovePoints | None = None,
    hangings: Sequence[Sequence[int]] | None = None,
    filtered: Mapping[int, FilteredCloud] | None = None,
    on_stage: StageListener | None = None,
    eyes_of: Callable[[int, np.ndarray], np.ndarray] | None = None,
    fixtures: Sequence[FixtureLine] = (),
    arriving: ArrivingPairs | None = None,
    leave_out_unaligned: bool = False,
) -> ReconstructionResult:
    """The whole reconstruction on in-memory views (see the module docstring).

    Args:
        views: one cloud per capture, in its camera frame C, with the flange pose X_WF.
        X_FC_nominal: the hand-eye transform the software believes (4x4, metres).
        config: every stage's settings (filter, ICP, pose graph, hand-eye, hangings, surfaces).
        remove_points: the caller's filter of points on the robot and cell (robots/ provides
            one from the Drake geometry; None keeps every point).
        hangings: the capture indices of each pass of a multi-hanging scan (None: one pass);
            the passes are aligned into the first one's frame.
        filtered: clouds of views already filtered at the kinematic pose with these settings
            (the filter stage skips them).
        on_stage: hears each stage start and end (a progress display).
        eyes_of: `eyes_of(index, X_WC)`, a view's camera centres in W (a stereo rig: both
            eyes, as `coverage_estimate` takes them); given, the coverage is estimated while
            the meshes are built.
        fixtures: the line of the rod each hanging hung from, in its own frame (one for all
            hangings, or one per hanging); the model is guarded against a strip along it.
        arriving: the pairs registered while the views arrived (the view stream), used when
            they are this run's first views with these clouds, X_FC and ICP settings.
        leave_out_unaligned: a hanging whose alignment fails its verification is left out of
            the model (its views in no result but the coverage per hanging, its alignment
            recorded unverified) instead of refusing the whole result.

    Returns:
        The views' poses (kinematic, registered, final), the registration edges, the X_FC used
        and the hand-eye story, the fused cloud, the meshes by method, the stage times, the
        skipped views and notes, the hangings' alignments and the coverage estimate.

    Raises:
        ScannerError: fewer usable views than `config.min_views`, or (RefusedResultError) a
            hanging whose alignment fails its verification, unless `leave_out_unaligned`."""
    X_FC_nominal = check_pose(X_FC_nominal, "X_FC_nominal")
    indices = [v.index for v in views]
    if len(set(indices)) != len(indices):
        raise ScannerError("views: capture indices must be unique")
    timer = StageTimer(on_stage=on_stage)
    notes: list[str] = []
    if any(m.startswith("poisson") for m in config.surfaces.methods):
        start_solver()  # its imports run while the views are registered

    all_views = list(views)
    with timer("filter"):
        views, clouds, skipped = filter_views(
            all_views, X_FC_nominal, config.filter, remove_points, filtered
        )
    _require_views(views, skipped, config)
    groups = group_positions(views, hangings or [[v.index for v in views]])
    coarse = None
    X_FC_start = X_FC_nominal
    X_FC_filtered = X_FC_nominal  # the X_FC the clouds were cropped and cleaned with
    pairing = (config.icp.enabled or config.handeye.enabled) and len(views) >= 2
    holding, streamed = None, len(arriving.pairs()) if arriving is not None else 0
    if pairing:
        with timer("icp"):
            # Offline, or views the scan did not stream: pairwise ICP as if they arrived now.
            given, arriving = (
                arriving,
                arrived_pairs(arriving, views, clouds, groups, X_FC_filtered, config.icp),
            )
        holding, streamed = share_holding(arriving), streamed if arriving is given else 0
    if (
        config.handeye.enabled
        and config.handeye.coarse.enabled
        and len(views) >= 3
        and (holding is None or holding < config.handeye.coarse.skip_when_pairs_hold)
    ):
        with timer("handeye_coarse"):
            coarse = coarse_handeye(
                clouds,
                [v.X_WF for v in views],
                groups,
                X_FC_nominal,
                config.handeye.coarse,
                config.handeye.seed,
            )
        if coarse is not None and plausible_correction(coarse.X_FC, X_FC_nominal, config.handeye):
            X_FC_start = coarse.X_FC
    registered = RegisteredViews((), None, (), ())
    handeye = None
    X_FC = X_FC_nominal
    # Registration (ICP from X_WF @ X_FC) and the correction of X_FC feed each other: when the
    # correction moves X_FC, ICP ran from stale poses (and the AX = XB check compares with
    # them), so register again from the corrected X_FC until it stops moving.
    for _ in range(max(config.handeye.max_rounds, 1)):
        distance_m = _working_distance_m(clouds)
        moved = displacement_at(X_FC_filtered, X_FC_start, distance_m)
        if moved > config.handeye.coarse.refilter_above_m:
            # The crop and the robot's points are placed in W: redo them at the new poses.
            with timer("filter"):
                views, clouds, skipped = filter_views(
                    all_views, X_FC_start, config.filter, remove_points
                )
            _require_views(views, skipped, config)
            groups = group_positions(views, hangings or [[v.index for v in views]])
            X_FC_filtered = X_FC_start
            if pairing:
                with timer("icp"):
                    arriving = arrived_pairs(None, views, clouds, groups, X_FC_start, config.icp)
        X_WF = [v.X_WF for v in views]
        X_WC_start = [X @ X_FC_start for X in X_WF]
        if (config.icp.enabled or config.handeye.enabled) and len(views) >= 2:
            indices = [v.index for v in views]
            registered = register_hangings(
                X_WC_start, indices, groups, config.icp, config.pose_graph, timer, arriving
            )
        X_WC = list(registered.X_WC) if registered.X_WC is not None else X_WC_start
        if not (config.handeye.enabled and len(views) >= 2):
            break
        with timer("handeye"):
            handeye = correct_handeye(
                clouds,
                X_WF,
                registered.X_WC,
                registered.pairs,
                X_FC_nominal,
                config.handeye,
                coarse,
                X_FC_start,
            )
        X_FC = handeye.X_FC
        kept = {(indices[e.source], indices[e.target]) for e in registered.kept_edges}
        if displacement_at(X_FC_start, X_FC, distance_m) <= config.handeye.round_tolerance_m or (
            config.icp.enabled
            and not outside_basin(arriving, kept, indices, [X @ X_FC for X in X_WF])
        ):
            # From the corrected mount ICP would end where it ended on every kept pair: the
            # same edges, the same correction.
            break
        X_FC_start = X_FC
    X_WC_kin = [X @ X_FC_nominal for X in X_WF]
    if (config.icp.enabled or config.handeye.enabled) and len(views) >= 2 and not registered.pairs:
        notes.append("no overlapping view pairs: registration and correction skipped")
    if handeye is not None:
        notes += handeye.notes
        X_WC = [X @ X_FC for X in X_WF]
        if config.final_pose_graph and registered.kept_edges:
            with timer("pose_graph"):
                graph = optimise_pose_graph(X_WC, registered.kept_edges, config.pose_graph)
            X_WC = list(graph.X_WC)

    if remove_points is not None:
        # The rod and the robot once more, each view at its final pose in its hanging's frame.
        with timer("filter"):
            clouds = [refiltered(c, X, remove_points) for c, X in zip(clouds, X_WC)]
    voxel_m = config.surfaces.fused_voxel_size_m
    with timer("align") if len(groups) > 1 else nullcontext():
        placed = place_hangings(
            views,
            clouds,
            X_WC,
            groups,
            config.alignment,
            voxel_m,
            fixtures,
            remove_points,
            leave_out_unaligned,
        )
    X_WC, alignments, kept = placed.X_WC, placed.alignments, placed.kept
    hanging_of = {k: h for h, group in enumerate(groups) for k in group}
    if len(groups) - len(left_out(alignments)) > 1 and "poisson" in config.surfaces.methods:
        # Hangings together surround the object: its closed model comes from the same solve.
        methods = tuple(dict.fromkeys((*config.surfaces.methods, "poisson_closed")))
        config = replace(config, surfaces=replace(config.surfaces, methods=methods))
    coverage: list[Coverage] = []

    def estimate_coverage(fused: FusedCloud) -> None:
        with timer("coverage"):
            eyes = [eyes_of(v.index, X) for v, X in zip(views, X_WC)]
            coverage.append(coverage_estimate(fused, [eyes[k] for k in kept]))
            for group in map(sorted, groups if len(groups) > 1 else ()):
                alone = fuse_clouds([clouds[k] for k in group], [X_WC[k] for k in group], voxel_m)
                coverage.append(coverage_estimate(alone, [eyes[k] for k in group]))

    fused, meshes, surface_notes = build_surfaces(
        [views[k] for k in kept],
        [clouds[k] for k in kept],
        [X_WC[k] for k in kept],
        config,
        placed.remove_points,
        timer,
        estimate_coverage if eyes_of is not None else None,
        placed.fixtures,
    )
    fused_nominal = None
    if handeye is not None and not handeye.diagnosis.converged:
        # Nothing is lost: the model at the nominal poses stays beside the doubtful one.
        fused_nominal = fuse_clouds([clouds[k] for k in kept], [X_WC_kin[k] for k in kept], voxel_m)
    notes += surface_notes
    view_results = tuple(
        ViewResult(
            views[k].index,
            clouds[k].counts,
            X_WC_kin[k],
            None if registered.X_WC is None else registered.X_WC[k],
            X_WC[k],
            hanging_of[k],
        )
        for k in kept
    )
    return ReconstructionResult(
        views=view_results,
        edges=registered.report,
        X_FC_nominal=X_FC_nominal,
        X_FC=X_FC,
        handeye=handeye,
        fused=fused,
        meshes=meshes,
        timings_s=timer.seconds,
        skipped_views=tuple(skipped),
        notes=tuple(notes),
        clouds=tuple(clouds[k] for k in kept),
        alignments=alignments,
        fused_nominal=fused_nominal,
        coverage=coverage[0] if coverage else None,
        hanging_coverage=tuple(coverage[1:]),
        pairs_before=streamed,
    )


def _require_views(views, skipped, config: ReconstructionConfig) -> None:
    if len(views) < config.min_views:
        raise ScannerError(
            f"only {len(views)} usable view(s) after filtering, {config.min_views} needed "
            f"(skipped: {', '.join(f'{i}: {why}' for i, why in skipped) or 'none'})"
        )


def _working_distance_m(clouds: Sequence[FilteredCloud]) -> float:
    return float(np.mean([np.median(c.points_C[:, 2]) for c in clouds if len(c)]))

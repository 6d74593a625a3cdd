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

`reconstruct_views` reads as its steps, each a function of its own: filter
(`handeye.rounds.filter_step`), register and correct (`handeye.rounds.register_and_correct`),
the final poses (`final_poses`), the hangings placed in the first one's frame, the surfaces
(`build_surfaces`, also what a benchmark calls with other pose sets). No file I/O here:
`reconstruction.outputs` writes the files and the plain record of a result.
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
from reconstruction.config import ReconstructionConfig
from reconstruction.evaluation.coverage import Coverage, coverage_estimate
from reconstruction.evaluation.support import SupportPlane
from reconstruction.handeye.correction import HandEyeResult
from reconstruction.handeye.rounds import (
    CorrectedViews,
    CorrectionInputs,
    FilteredViews,
    filter_step,
    register_and_correct,
)
from reconstruction.hangings.alignment import PassAlignment
from reconstruction.hangings.merge import (
    PlacedHangings,
    left_out,
    place_hangings,
    placed_supports,
)
from reconstruction.hangings.turntable import KnownTurns
from reconstruction.registration.all_views import EdgeReport
from reconstruction.registration.filtering import (
    VIEW_THREADS,
    FilterCounts,
    FilteredCloud,
    RemovePoints,
    refiltered,
)
from reconstruction.registration.incremental import ArrivingPairs
from reconstruction.registration.posegraph import optimise_pose_graph
from reconstruction.registration.views import ViewCloud
from reconstruction.surfaces.build import surface_from
from reconstruction.surfaces.fixture import FixtureLine, without_fixture
from reconstruction.surfaces.fused import FusedCloud, fuse_clouds, refine_fused
from reconstruction.surfaces.meshes import DepthView, SurfaceInput, SurfaceMesh
from reconstruction.surfaces.poisson_solver import start_solver


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


@dataclass(frozen=True, eq=False, kw_only=True)
class ReconstructionInputs:
    """What one reconstruction works on.

    views: one cloud per capture, in its camera frame C, with the flange pose X_WF.
    X_FC_nominal: the hand-eye transform the software believes (4x4, metres).
    config: every stage's settings (filter, ICP, pose graph, hand-eye, hangings, surfaces).
    remove_points: the caller's filter of points on the robot and cell (robots/ provides one
        from the Drake geometry; None keeps every point).
    hangings: the capture indices of each pass of a multi-hanging scan (None: one pass); the
        passes are aligned into the first one's frame.
    filtered: clouds of views already filtered at the kinematic pose with these settings (the
        filter stage skips them).
    eyes_of: `eyes_of(index, X_WC)`, a view's camera centres in W (a stereo rig: both eyes, as
        `coverage_estimate` takes them); given, the coverage is estimated while the meshes are
        built.
    fixtures: the line of the rod each hanging hung from, in its own frame (one for all
        hangings, or one per hanging); the model is guarded against a strip along it.
    arriving: the pairs registered while the views arrived (the view stream), used when they
        are this run's first views with these clouds, X_FC and ICP settings.
    leave_out_unaligned: a hanging whose alignment fails its verification is left out of the
        model (its views in no result but the coverage per hanging, its alignment recorded
        unverified) instead of refusing the whole result.
    turns: the passes' known turns (a turntable's angles and axis), the starting guess of
        each pass's alignment (None: the object was re-hung, the turn is unknown).
    earlier_alignments: by hanging, its alignment found on these captures while they were
        scanned (the quick model of `hangings: auto`): refined and verified again rather than
        searched for anew.
    supports: per hanging, the top of what held the object from below in its own frame
        (None: it hung), which hides what lay on it from the coverage estimate's views."""

    views: Sequence[ViewCloud]
    X_FC_nominal: np.ndarray
    config: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    remove_points: RemovePoints | None = None
    hangings: Sequence[Sequence[int]] | None = None
    filtered: Mapping[int, FilteredCloud] | None = None
    eyes_of: Callable[[int, np.ndarray], np.ndarray] | None = None
    fixtures: Sequence[FixtureLine] = ()
    arriving: ArrivingPairs | None = None
    leave_out_unaligned: bool = False
    turns: KnownTurns | None = None
    supports: Sequence[SupportPlane | None] = ()
    earlier_alignments: Mapping[int, PassAlignment] | None = None


def solver_processes(config: ReconstructionConfig, coverage: bool) -> int:
    """Poisson solver processes a reconstruction uses at once: one for the model's Poisson
    surface, one for the coverage estimate's closed surface solved beside it."""
    poisson = any(m.startswith("poisson") for m in config.surfaces.methods)
    return int(poisson) + int(coverage)


def reconstruct_views(
    inputs: ReconstructionInputs, on_stage: StageListener | None = None
) -> ReconstructionResult:
    """The whole reconstruction on in-memory views (see the module docstring); `on_stage`
    hears each stage start and end (a progress display).

    Returns:
        The views' poses (kinematic, registered, final), the registration edges, the X_FC used
        and the hand-eye story, the fused cloud, the meshes by method, the stage times, the
        skipped views and notes, the hangings' alignments and the coverage estimate.

    Raises:
        ScannerError: fewer usable views than `config.min_views`, or (RefusedResultError) a
            hanging whose alignment fails its verification, unless `leave_out_unaligned`."""
    X_FC_nominal = check_pose(inputs.X_FC_nominal, "X_FC_nominal")
    config = inputs.config
    timer = StageTimer(on_stage=on_stage)
    # The solver processes' imports run while the views are registered (a scan's view stream
    # starts them earlier still).
    start_solver(solver_processes(config, inputs.eyes_of is not None))
    corrected = corrected_views(inputs, timer)
    final = final_poses(corrected, X_FC_nominal, config, timer)
    placed = _place_hangings(inputs, corrected.filtered, final, timer)
    return _surfaces(inputs, X_FC_nominal, corrected, final, placed, timer)


def corrected_views(
    inputs: ReconstructionInputs, timer: StageTimer | None = None
) -> CorrectedViews:
    """The reconstruction's first steps alone: the views filtered, registered and the mount
    corrected (what a scan's quick model needs of it; no surfaces)."""
    X_FC_nominal = check_pose(inputs.X_FC_nominal, "X_FC_nominal")
    indices = [v.index for v in inputs.views]
    if len(set(indices)) != len(indices):
        raise ScannerError("views: capture indices must be unique")
    config, timer = inputs.config, timer or StageTimer()
    correction = CorrectionInputs(
        views=list(inputs.views),
        X_FC_nominal=X_FC_nominal,
        filter=config.filter,
        icp=config.icp,
        pose_graph=config.pose_graph,
        handeye=config.handeye,
        min_views=config.min_views,
        remove_points=inputs.remove_points,
        hangings=inputs.hangings,
        arriving=inputs.arriving,
    )
    first = filter_step(correction, X_FC_nominal, timer, inputs.filtered)
    return register_and_correct(correction, first, timer)


@dataclass(frozen=True, eq=False)
class FinalPoses:
    """Every view's camera pose: kinematic (nominal X_FC) and final (the corrected X_FC, or
    the registration's without a correction), each in its own hanging's frame; notes."""

    X_WC_kinematic: list[np.ndarray]
    X_WC: list[np.ndarray]
    notes: list[str]


def final_poses(
    corrected: CorrectedViews,
    X_FC_nominal: np.ndarray,
    config: ReconstructionConfig,
    timer: StageTimer,
) -> FinalPoses:
    """The poses the model is built from: X_WF @ X_FC with the corrected X_FC (polished by one
    more pose graph when `final_pose_graph`), else where registration left them."""
    views, registered = corrected.filtered.views, corrected.registered
    X_WF = [v.X_WF for v in views]
    notes: list[str] = []
    X_WC = corrected.X_WC
    if (config.icp.enabled or config.handeye.enabled) and len(views) >= 2 and not registered.pairs:
        notes.append("no overlapping view pairs: registration and correction skipped")
    if corrected.handeye is not None:
        notes += corrected.handeye.notes
        X_WC = [X @ corrected.X_FC for X in X_WF]
        if config.final_pose_graph and registered.kept_edges:
            with timer("pose_graph"):
                graph = optimise_pose_graph(X_WC, registered.kept_edges, config.pose_graph)
            X_WC = list(graph.X_WC)
    return FinalPoses([X @ X_FC_nominal for X in X_WF], X_WC, notes)


@dataclass(frozen=True, eq=False)
class _Placed:
    """The views' clouds filtered once more at their final poses, and the hangings placed in
    the first one's frame."""

    clouds: list[FilteredCloud]
    hangings: PlacedHangings


def _place_hangings(
    inputs: ReconstructionInputs, filtered: FilteredViews, final: FinalPoses, timer: StageTimer
) -> _Placed:
    clouds = filtered.clouds
    if inputs.remove_points is not None:
        # The rod and the robot once more, each view at its final pose in its hanging's frame.
        with timer("filter"), ThreadPoolExecutor(max_workers=VIEW_THREADS) as pool:
            clouds = list(
                pool.map(lambda c, X: refiltered(c, X, inputs.remove_points), clouds, final.X_WC)
            )
    with timer("align") if len(filtered.groups) > 1 else nullcontext():
        placed = place_hangings(
            filtered.views,
            clouds,
            final.X_WC,
            filtered.groups,
            inputs.config.alignment,
            inputs.config.surfaces.fused_voxel_size_m,
            inputs.fixtures,
            inputs.remove_points,
            inputs.leave_out_unaligned,
            inputs.turns,
            inputs.earlier_alignments,
        )
    return _Placed(clouds, placed)


def _surface_config(
    config: ReconstructionConfig, groups: Sequence[Sequence[int]], placed: PlacedHangings
) -> ReconstructionConfig:
    """Hangings that together surround the object (two or more in the model) also give its
    closed model, from the same solve."""
    if len(groups) - len(left_out(placed.alignments)) > 1 and "poisson" in config.surfaces.methods:
        methods = tuple(dict.fromkeys((*config.surfaces.methods, "poisson_closed")))
        return replace(config, surfaces=replace(config.surfaces, methods=methods))
    return config


def _surfaces(
    inputs: ReconstructionInputs,
    X_FC_nominal: np.ndarray,
    corrected: CorrectedViews,
    final: FinalPoses,
    placed: _Placed,
    timer: StageTimer,
) -> ReconstructionResult:
    """The fused cloud and the meshes from the kept views at their placed poses (with the
    coverage estimated beside them), and the result."""
    views, groups = corrected.filtered.views, corrected.filtered.groups
    clouds, hangings = placed.clouds, placed.hangings
    X_WC, kept = hangings.X_WC, hangings.kept
    config = _surface_config(inputs.config, groups, hangings)
    voxel_m = config.surfaces.fused_voxel_size_m
    coverage: list[Coverage] = []

    supports = placed_supports(inputs.supports, groups, hangings.alignments, len(views))

    def estimate_coverage(fused: FusedCloud) -> None:
        with timer("coverage"):
            eyes = [inputs.eyes_of(v.index, X) for v, X in zip(views, X_WC)]
            coverage.append(
                coverage_estimate(
                    fused,
                    [eyes[k] for k in kept],
                    supports=supports and [supports[k] for k in kept],
                )
            )
            for group in map(sorted, groups if len(groups) > 1 else ()):
                alone = fuse_clouds([clouds[k] for k in group], [X_WC[k] for k in group], voxel_m)
                group_supports = supports and [supports[k] for k in group]
                coverage.append(
                    coverage_estimate(alone, [eyes[k] for k in group], supports=group_supports)
                )

    fused, meshes, surface_notes = build_surfaces(
        [views[k] for k in kept],
        [clouds[k] for k in kept],
        [X_WC[k] for k in kept],
        config,
        hangings.remove_points,
        timer,
        estimate_coverage if inputs.eyes_of is not None else None,
        hangings.fixtures,
    )
    fused_nominal = None
    handeye = corrected.handeye
    if handeye is not None and not handeye.diagnosis.converged:
        # Nothing is lost: the model at the nominal poses stays beside the doubtful one.
        X_kin = final.X_WC_kinematic
        fused_nominal = fuse_clouds([clouds[k] for k in kept], [X_kin[k] for k in kept], voxel_m)
    hanging_of = {k: h for h, group in enumerate(groups) for k in group}
    registered = corrected.registered
    view_results = tuple(
        ViewResult(
            views[k].index,
            clouds[k].counts,
            final.X_WC_kinematic[k],
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
        X_FC=corrected.X_FC,
        handeye=handeye,
        fused=fused,
        meshes=meshes,
        timings_s=timer.seconds,
        skipped_views=tuple(corrected.filtered.skipped),
        notes=tuple([*final.notes, *surface_notes]),
        clouds=tuple(clouds[k] for k in kept),
        alignments=hangings.alignments,
        fused_nominal=fused_nominal,
        coverage=coverage[0] if coverage else None,
        hanging_coverage=tuple(coverage[1:]),
        pairs_before=corrected.pairs_before,
    )

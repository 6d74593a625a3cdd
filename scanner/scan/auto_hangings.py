"""`--hangings auto`: after each hanging, how much of the object the passes so far have seen
(without truth), whether to ask for another hanging, and how to turn the object for it.

Each hanging's quick model is its views' clouds (the per-view work the scan streams anyway)
at the robot's poses with the mount corrected on the first hanging, without the fixture; each
further hanging is aligned onto the ones before it as the final reconstruction will (the
alignment's verification is logged here and stops asking for hangings; the reconstruction
verifies again and leaves out a hanging that fails). The coverage is that of the
final report (`seen_surface`: seen and held by the data), so the decision and the report agree
on what "seen" means.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from reconstruction.common.transforms import invert, rotate_vectors, transform_points
from reconstruction.evaluation.coverage import SeenSurface, seen_surface
from reconstruction.evaluation.metrics import SurfaceSamples, TriangleSurface
from reconstruction.hangings.alignment import PassAlignment, align_pass
from reconstruction.hangings.free_space import SeenSpace
from reconstruction.pipeline import ReconstructionInputs, corrected_views
from reconstruction.registration.filtering import filter_views, o3d_cloud, refiltered
from reconstruction.surfaces.fixture import without_fixture
from reconstruction.surfaces.fused import FusedCloud, fuse_clouds
from scanner.configs.scan import ScanConfig
from scanner.reconstruct.scan_views import (
    capture_views,
    fixture_line,
    geometry_filter,
    prepare_sensor,
    support_plane,
    with_roi_centre,
)
from scanner.reconstruct.view_stream import ViewStream
from scanner.scan_dir.known_turns import known_turns
from scanner.scan_dir.manifest import SavedScan
from scanner.scan_dir.quick_alignments import quick_alignments

log = logging.getLogger("scanner.scan.auto_hangings")

SAMPLES = 20_000


@dataclass(frozen=True, eq=False)
class QuickPass:
    """One hanging's model at the kinematic poses, in its own frame: the fused cloud, each
    view's stereo eye centres, and its depth maps with their camera poses."""

    fused: FusedCloud
    eyes: list[np.ndarray]
    depths: list
    X_WC: list[np.ndarray]


@dataclass(frozen=True, eq=False)
class Assessment:
    """What the hangings so far have seen: the share of the closed model, that model in the
    frame of the last hanging, and whether that hanging's alignment verified."""

    fraction: float
    seen: SeenSurface
    failures: tuple[str, ...]  # the checks the last hanging's alignment failed

    @property
    def verified(self) -> bool:
        return not self.failures


class HangingAssessor:
    """Quick models of each hanging (made once) and their alignment onto the first."""

    def __init__(self, scan: SavedScan, stream: ViewStream | None) -> None:
        self.scan, self.stream = scan, stream
        self.passes: dict[int, QuickPass] = {}
        self.T: dict[int, np.ndarray] = {0: np.eye(4)}  # hanging -> the first's frame
        self.failures: dict[int, tuple[str, ...]] = {0: ()}
        self.alignments: dict[int, PassAlignment] = {}  # hanging -> its quick alignment
        self.X_FC: np.ndarray | None = None  # the mount, corrected on the first hanging

    def _views(self, indices: list[int]):
        """The hanging's views and their filtered clouds (the streamed ones where the scan
        streamed them), the filter of the rod and robot, and the pairs the stream registered."""
        scan = self.scan
        processing = scan.config.processing
        config = with_roi_centre(processing.reconstruction, np.array(scan.config.scan_center_m))
        ready, done, arriving = {}, {}, None
        if self.stream is not None:
            so_far = self.stream.so_far()
            streamed, arriving = so_far.views, so_far.arriving
            ready = {i: (streamed[i].view, streamed[i].q_rad) for i in indices if i in streamed}
            done = {i: streamed[i].cloud for i in ready if streamed[i].cloud is not None}
        X_FC, stereo = scan.X_FC_nominal, scan.camera_model
        captured = capture_views(
            scan, prepare_sensor(scan, stereo), X_FC, processing.stereo, indices, ready
        )
        remove = geometry_filter(
            scan.config, X_FC, stereo, captured.joints, processing.remove_margin_m
        )
        views, clouds, _ = filter_views(captured.views, X_FC, config.filter, remove, done)
        return views, clouds, remove, config, arriving

    def _quick(self, indices: list[int]) -> QuickPass:
        views, clouds, remove, config, arriving = self._views(indices)
        if self.X_FC is None:
            # The first hanging's views correct the mount (ICP, pose graph, hand-eye) as the
            # final reconstruction will: the mount is the same in every hanging, and at the
            # nominal one each view is up to a centimetre off, which blurs a quick model too
            # much to align the next hanging onto it.
            corrected = corrected_views(
                ReconstructionInputs(
                    views=views,
                    X_FC_nominal=self.scan.X_FC_nominal,
                    config=config,
                    remove_points=remove,
                    filtered={c.index: c for c in clouds},
                    # The pairs the scan registered as the views arrived: not registered again.
                    arriving=arriving,
                )
            )
            self.X_FC = corrected.X_FC
        X_WC = [v.X_WF @ self.X_FC for v in views]
        clouds = [refiltered(c, X, remove) for c, X in zip(clouds, X_WC)]
        fused = fuse_clouds(clouds, X_WC, config.surfaces.fused_voxel_size_m)
        keep = without_fixture(fused.points_W, [fixture_line(self.scan.config)])
        fused = FusedCloud(fused.points_W[keep], fused.colors[keep], fused.normals_W[keep])
        stereo = self.scan.camera_model
        return QuickPass(
            fused,
            [stereo.eye_centres_W(X) for X in X_WC],
            [v.depth for v in views if v.depth is not None],
            [X for v, X in zip(views, X_WC) if v.depth is not None],
        )

    def assess(self, hangings: list[list[int]], hanging: int, captured: set[int]) -> Assessment:
        """The coverage of hangings 0..`hanging` together (their captured views), and the
        closed model in the frame of `hanging`."""
        for h in range(hanging + 1):
            if h not in self.passes:
                self.passes[h] = self._quick([i for i in hangings[h] if i in captured])
            if h not in self.T:
                self._align(h)
        points, normals, colors, eyes, supports = [], [], [], [], []
        support = support_plane(self.scan.config)
        for h in range(hanging + 1):
            T, q = self.T[h], self.passes[h]
            points.append(transform_points(T, q.fused.points_W))
            normals.append(rotate_vectors(T, q.fused.normals_W))
            colors.append(q.fused.colors)
            eyes += [transform_points(T, e) for e in q.eyes]
            # Each pass's support, where the pass put it: what lay on it was not seen.
            supports += [None if support is None else support.moved(T)] * len(q.eyes)
        voxel = self.scan.config.processing.reconstruction.surfaces.fused_voxel_size_m
        pc = o3d_cloud(np.vstack(points), np.vstack(normals), np.vstack(colors)).voxel_down_sample(
            voxel
        )
        n = np.asarray(pc.normals)
        merged = FusedCloud(
            np.asarray(pc.points),
            np.clip(np.round(np.asarray(pc.colors) * 255), 0, 255).astype(np.uint8),
            n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12),
        )
        seen = seen_surface(merged, eyes, SAMPLES, supports=supports)
        return Assessment(
            seen.fraction, _moved(seen, invert(self.T[hanging])), self.failures[hanging]
        )

    def _align(self, h: int) -> None:
        a = self._aligned(h, self.passes[h], quick_alignments(self.scan).get(h))
        if a.failures:
            # The final reconstruction verifies again (and leaves the hanging out of the model);
            # here the best fit still tells what was seen and how to turn the object next.
            log.warning(
                "hanging %d: its quick model does not verify against the hangings before it "
                "(%s); the final alignment decides",
                h + 1,
                "; ".join(a.failures),
            )
        self.T[h], self.failures[h] = a.T, tuple(a.failures)
        self.alignments[h] = a

    def _aligned(self, h: int, q: QuickPass, earlier: PassAlignment | None) -> PassAlignment:
        """Pass `h`'s quick model `q` aligned onto the passes before it (`earlier`: an
        alignment of it found before, refined instead of searched for again)."""
        reference = [self.passes[k] for k in range(h)]
        ref_points = np.vstack(
            [transform_points(self.T[k], p.fused.points_W) for k, p in enumerate(reference)]
        )
        ref_colors = np.vstack([p.fused.colors for p in reference])
        seen = SeenSpace(
            tuple(d for p in reference for d in p.depths),
            tuple(self.T[k] @ X for k, p in enumerate(reference) for X in p.X_WC),
        )
        # On a turntable the known turn starts the alignment, about the axis the verified
        # turns before it calibrate.
        turns = known_turns(self.scan, h + 1)
        verified = [(k, self.T[k]) for k in range(1, h) if not self.failures[k]]
        return align_pass(
            h,
            q.fused.points_W,
            ref_points,
            seen,
            self.scan.config.processing.reconstruction.alignment,
            q.fused.colors,
            ref_colors,
            start=None if turns is None else turns.start(h, verified),
            earlier=earlier,
        )

    def passes_before(self, hangings: list[list[int]], hanging: int, captured: set[int]) -> None:
        """The quick models of the passes before `hanging` (their `captured` views), each
        aligned onto those before it; those made already are kept."""
        for h in range(hanging):
            if h not in self.passes:
                self.passes[h] = self._quick([i for i in hangings[h] if i in captured])
            if h not in self.T:
                self._align(h)

    def early_alignment(
        self, hangings: list[list[int]], hanging: int, captured: set[int]
    ) -> PassAlignment:
        """Pass `hanging` aligned from the views it has so far (`captured`) onto the passes
        before it (their whole quick models, made and aligned here when not yet): the search
        for hypotheses, run while the rest of the pass is captured, so that after its last
        picture the alignment is only refined."""
        self.passes_before(hangings, hanging, captured)
        partial = self._quick([i for i in hangings[hanging] if i in captured])
        return self._aligned(hanging, partial, None)


def _moved(seen: SeenSurface, T: np.ndarray) -> SeenSurface:
    """The same seen surface after the rigid transform T."""
    surface = TriangleSurface(transform_points(T, seen.surface.vertices), seen.surface.triangles)
    samples = SurfaceSamples(
        transform_points(T, seen.samples.points), rotate_vectors(T, seen.samples.normals)
    )
    return replace(seen, surface=surface, samples=samples)


@dataclass(frozen=True)
class Decision:
    """After a hanging: stop (with the reason) or ask for another."""

    another: bool
    reason: str


def decide(config: ScanConfig, coverage: list[float], failures: tuple[str, ...] = ()) -> Decision:
    """`coverage`: the estimate after each hanging so far (the last is the current one);
    `failures`: the checks the last hanging's quick alignment failed (its coverage is then
    not what was seen: a wrong fit puts it over what the others saw)."""
    c, n = coverage[-1], len(coverage)
    target = config.coverage_target
    if failures:
        return Decision(
            False,
            f"hanging {n} could not be aligned with the hangings before it ({'; '.join(failures)});"
            " another hanging cannot be placed either, and the reconstruction verifies again",
        )
    if c >= target:
        return Decision(False, f"coverage {c:.3f} reached the target {target:.2f}")
    if n >= 2 and c - coverage[-2] < config.min_hanging_gain:
        return Decision(
            False,
            f"hanging {n} added {c - coverage[-2]:.3f} of the surface, less than "
            f"{config.min_hanging_gain:.2f}: more hangings would not finish it (coverage {c:.3f})",
        )
    if n >= config.max_hangings:
        return Decision(
            False,
            f"max_hangings ({config.max_hangings}) done with coverage {c:.3f}, below the "
            f"target {target:.2f}",
        )
    return Decision(True, f"coverage {c:.3f} is below the target {target:.2f}")

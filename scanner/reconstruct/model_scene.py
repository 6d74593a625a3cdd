"""What a reconstruction's model.html shows (`scanner.reports.model_page`): its headline mesh
coloured by deviation, the unseen parts, the views, the fixture, the cell and the arm, all in the
first hanging's frame. Written after the results folder is complete: a page that fails to
write costs a warning, never a result."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reconstruction.hangings.merge import to_first_frame
from reconstruction.pipeline import ReconstructionResult
from robots.sensors import sensor_named
from scanner.configs.scan import ProcessingConfig
from scanner.reconstruct.scan_views import Gathered
from scanner.reports.model_page_layers import (
    DisplayMesh,
    ModelScene,
    RobotPose,
    ViewFrustum,
    decimated,
    thinned,
)

log = logging.getLogger("scanner.reconstruct.model_scene")

ROD_ABOVE_M = 0.8  # drawn length of a rod that does not hang straight down (a re-hung pass)


def headline_mesh(result: ReconstructionResult, primary: str):
    """The surface the report leads with (processing.primary_surface), else the first built."""
    mesh = result.meshes.get(primary)
    if mesh is not None and len(mesh.triangles):
        return mesh
    return next((m for m in result.meshes.values() if len(m.triangles)), None)


@dataclass(frozen=True, eq=False)
class Colouring:
    """Per displayed vertex the value its colour shows (m), what it is, and its scale: signed
    values span -scale_m..+scale_m (blue, white, red), unsigned ones 0..scale_m (white..red)."""

    values_m: np.ndarray
    meaning: str
    scale_m: float
    signed: bool


def colouring(
    vertices: np.ndarray, result: ReconstructionResult, truth, processing: ProcessingConfig
) -> Colouring:
    """With the truth, the signed deviation on the deviation pictures' fixed scale."""
    if truth is not None:
        from reconstruction.evaluation.deviation import signed_distances

        return Colouring(
            signed_distances(vertices, truth[1]),
            "signed deviation from the true surface",
            processing.deviation_scale_m,
            True,
        )
    from reconstruction.evaluation.coverage import SUPPORT_M
    from reconstruction.evaluation.metrics import distances_to_points

    # Without truth, the one per-point figure the reports compute is how far the surface is
    # from the fused measurements: the coverage estimate counts a part as seen only within
    # SUPPORT_M of them (the hangings' and the hand-eye agreement are single figures). On that
    # scale, saturated red is where the surface bridges what no view measured.
    return Colouring(
        distances_to_points(vertices, result.fused.points_W),
        "distance to the nearest measured (fused) point",
        SUPPORT_M,
        False,
    )


def _fixture_segments(views: Gathered, result: ReconstructionResult, rod_top_z_m: float):
    """Every placed hanging's rod axis in the first hanging's frame, up to the rod's top."""
    segments = []
    for line, T in zip(views.fixtures, to_first_frame(result.alignments), strict=False):
        if T is None:  # a hanging left out of the model
            continue
        moved = line.moved(T)
        p, u = np.array(moved.p_W), np.array(moved.u_W)
        length = rod_top_z_m - p[2] if u[2] > 0.99 else ROD_ABOVE_M
        segments.append((p, p + max(length, 0.05) * u))
    return tuple(segments)


def reconstruction_scene(
    result: ReconstructionResult,
    views: Gathered,
    processing: ProcessingConfig,
    scan,
    camera_model,
    truth=None,
    truth_samples=None,
) -> ModelScene | None:
    """The page's scene (None when no mesh was built). `scan`: the (first) SavedScan;
    `camera_model`: the one the views were computed with; `truth`: (Truth, true surface, file)
    or None; `truth_samples`: (samples of the true surface, which of them a view saw)."""
    mesh = headline_mesh(result, processing.primary_surface)
    if mesh is None:
        return None
    vertices, triangles = decimated(mesh.vertices, mesh.triangles)
    colours = colouring(vertices, result, truth, processing)
    unseen = None
    if truth_samples is not None and truth_samples[1] is not None:
        unseen = thinned(truth_samples[0].points[~truth_samples[1]])
    camera = sensor_named(scan.sensor).image_camera(camera_model)
    first = next((v for v in result.views if v.hanging == 0), None)
    robot = None
    if first is not None and first.index in views.joints:
        q = views.joints[first.index]
        robot = RobotPose(q, result.X_FC, camera_model.X_CR, scan.config.robot)
    cell = scan.config.cell
    return ModelScene(
        mesh=DisplayMesh(vertices, triangles, colours.values_m),
        scale_m=colours.scale_m,
        colour_meaning=f"{mesh.name} mesh: {colours.meaning}",
        signed=colours.signed,
        unseen_W=unseen,
        frustums=tuple(ViewFrustum(v.X_WC, v.hanging) for v in result.views),
        camera=camera,
        fixture_segments=_fixture_segments(views, result, cell.rod_top_z_m),
        cell=cell,
        robot=robot,
    )


def write_reconstruction_page(out: Path, build_scene) -> float | None:
    """model.html in the results folder `out` from `build_scene()` (a ModelScene or None);
    the seconds it took, or None when it was not written (logged as a warning: the results
    are complete without it)."""
    from scanner.reports.model_page import PAGE_NAME, write_model_page

    t0 = time.perf_counter()
    try:
        scene = build_scene()
        if scene is None:
            return None
        write_model_page(scene, Path(out) / PAGE_NAME, f"scanner: {Path(out).name}")
    except Exception as e:  # noqa: BLE001 - any failure of the page leaves the results whole
        log.warning(
            "%s not written (%s: %s); the results are complete without it",
            Path(out) / PAGE_NAME,
            type(e).__name__,
            e,
        )
        return None
    return time.perf_counter() - t0

"""`scanner reconstruct` of an imported recording: pairs of one camera's views to clouds, the
product's pipeline to a model, and the measures a recording without a reference surface allows.

    views -> working volume (given | masks' hull | common view) -> pairs -> pair clouds
      -> region of interest: the volume, the masks' hull, the table found in the data
      -> filter, register, fuse, surfaces (reconstruction.pipeline; no hand-eye correction when
         the recording gave camera poses)
      -> silhouettes on the views whose masks were not used, split-half agreement
      -> results folder (written whole or not at all), report.json, summary.md
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.stage_timer import StageTimer
from reconstruction.common.transforms import transform_points
from reconstruction.common.yaml_files import yaml_text
from reconstruction.evaluation.silhouette import (
    SilhouetteAgreement,
    cloud_silhouette_agreement,
    silhouette_agreement,
)
from reconstruction.evaluation.split_half import SplitHalf, split_half_agreement
from reconstruction.outputs import save_outputs, summary
from reconstruction.pipeline import (
    ReconstructionConfig,
    ReconstructionInputs,
    ReconstructionResult,
    reconstruct_views,
)
from reconstruction.registration.filtering import RegionOfInterest
from reconstruction.surfaces.export import prepare_exports
from reconstruction.surfaces.fused import fuse_clouds
from reconstruction.working_volume.table import TablePlane, above_table, find_table
from reconstruction.working_volume.volume import WorkingVolume
from scanner.recordings.settings import RecordingProcessing
from scanner.recordings.views import (
    PairedClouds,
    RecordedViews,
    footprint_m,
    hull_keep,
    mask_used,
    paired_clouds,
    read_recorded_views,
    working_volume,
)
from scanner.reports.self_checks import self_check_record
from scanner.scan_dir.captures import atomic_write_text
from scanner.scan_dir.manifest import SavedScan
from scanner.scan_dir.outputs import RECONSTRUCTION_MARKER
from scanner.scan_dir.results_folder import staged_folder

log = logging.getLogger("scanner.recordings")

# Points sampled per pair cloud for finding the table (a plane fit needs no more).
TABLE_SAMPLES_PER_PAIR = 4000


@dataclass(frozen=True, eq=False)
class RecordingRun:
    result: ReconstructionResult
    report: dict
    results_dir: Path


def pipeline_config(
    settings: RecordingProcessing, volume: WorkingVolume, footprint: float, poses_given: bool
) -> ReconstructionConfig:
    """The pipeline's settings for this recording: its volume as the region of interest, grids
    from its pixel footprint, and no hand-eye correction when the camera poses were given."""
    rec = settings.reconstruction
    voxel = settings.voxel_footprints * footprint
    roi = RegionOfInterest("sphere", tuple(map(float, volume.centre_W)), float(volume.radius_m))
    fused = settings.fused_footprints * footprint
    surfaces = replace(
        rec.surfaces,
        fused_voxel_size_m=fused,
        tsdf_voxel_size_m=fused,
        poisson_max_distance_m=settings.poisson_trim_footprints * footprint,
    )
    handeye = replace(rec.handeye, enabled=rec.handeye.enabled and not poses_given)
    register = rec.icp.enabled and (settings.register_given_poses or not poses_given)
    return replace(
        rec,
        icp=replace(rec.icp, enabled=register),
        filter=replace(rec.filter, roi=roi, voxel_size_m=voxel),
        surfaces=surfaces,
        handeye=handeye,
    )


def table_of(
    views: RecordedViews, paired: PairedClouds, settings: RecordingProcessing
) -> TablePlane | None:
    """The table under the object, looked for only when some cloud is not restricted by its
    own mask (a masked cloud holds no table)."""
    unmasked = [
        k
        for k, i in enumerate(paired.references)
        if views.masks[i] is None or not mask_used(settings, i)
    ]
    if not unmasked:
        return None
    rng = np.random.default_rng(0)
    samples = []
    for k in unmasked:
        cloud, X_WC = paired.clouds[k], views.X_WC[paired.references[k]]
        n = len(cloud.points_C)
        pick = rng.choice(n, min(n, TABLE_SAMPLES_PER_PAIR), replace=False) if n else []
        samples.append(transform_points(X_WC, cloud.points_C[pick]))
    centres = [X[:3, 3] for X in views.X_WC]
    return find_table(np.vstack(samples), centres, settings.table)


def _keep_hook(views, settings, table: TablePlane | None):
    hull = hull_keep(views, settings)
    clearance = settings.table.clearance_m
    if hull is None and table is None:
        return None

    def keep(p_W: np.ndarray, index: int) -> np.ndarray:
        out = np.ones(len(p_W), bool)
        if hull is not None:
            out &= hull(p_W)
        if table is not None:
            out &= above_table(p_W, table, clearance)
        return out

    return keep


def _masked_views(views: RecordedViews, ks, X_WC):
    return [
        (
            views.cameras[k].K,
            X_WC[k],
            views.cameras[k].width,
            views.cameras[k].height,
            views.masks[k],
        )
        for k in ks
    ]


def measures(
    views: RecordedViews,
    paired: PairedClouds,
    result: ReconstructionResult,
    settings: RecordingProcessing,
    voxel_m: float,
) -> dict:
    """Silhouettes on the views whose masks the model did not use (all views with masks when
    it used them all: then not held out, and said so), and the split-half agreement of the
    clouds of even and odd reference views at their final poses."""
    final = {v.index: v.X_WC for v in result.views}
    # Each view's final camera pose: that of the pair it is the reference of.
    X_WC = list(views.X_WC)
    for k, i in enumerate(paired.references):
        if k in final:
            X_WC[i] = final[k]
    with_mask = [k for k, m in enumerate(views.masks) if m is not None]
    held_out = [k for k in with_mask if not mask_used(settings, k)]
    out: dict = {}
    scored = held_out or with_mask
    if scored:
        masked = _masked_views(views, scored, X_WC)
        mesh = result.meshes[settings.primary_surface]
        on_mesh = silhouette_agreement(mesh.vertices, mesh.triangles, masked)
        on_cloud = cloud_silhouette_agreement(result.fused.points_W, masked, voxel_m)
        out["silhouette"] = {
            "views": [views.indices[k] for k in scored],
            "held_out": bool(held_out),
            "mesh": _silhouette_record(on_mesh, views, scored),
            "fused_cloud": _silhouette_record(on_cloud, views, scored),
        }
    out["split_half"] = _split_half(paired, result, settings, voxel_m)
    return out


def _silhouette_record(a: SilhouetteAgreement, views: RecordedViews, scored) -> dict:
    record = a.summary()
    record["iou_worst_view"] = views.indices[scored[record["iou_worst_view"]]]
    record["coverage_worst_view"] = views.indices[scored[record["coverage_worst_view"]]]
    return record


def _split_half(paired: PairedClouds, result, settings: RecordingProcessing, voxel_m: float):
    by_view = {v.index: v for v in result.views}
    halves = {0: ([], []), 1: ([], [])}
    for cloud in result.clouds:
        view = by_view.get(cloud.index)
        if view is None:
            continue
        clouds, poses = halves[paired.references[cloud.index] % 2]
        clouds.append(cloud)
        poses.append(view.X_WC)
    if not halves[0][0] or not halves[1][0]:
        return None
    even = fuse_clouds(*halves[0], voxel_m)
    odd = fuse_clouds(*halves[1], voxel_m)
    s: SplitHalf = split_half_agreement(
        even.points_W, odd.points_W, settings.split_half_common_voxels * voxel_m
    )
    return {
        "median_mm": round(1e3 * s.median_m, 4) if math.isfinite(s.median_m) else None,
        "p90_mm": round(1e3 * s.p90_m, 4) if math.isfinite(s.p90_m) else None,
        "common_share": round(s.common_share, 4),
        "common_radius_mm": round(1e3 * settings.split_half_common_voxels * voxel_m, 4),
    }


def reconstruct_recording(
    scan: SavedScan, settings: RecordingProcessing, out: Path, page: bool = True
) -> RecordingRun:
    """The model of an imported recording in `out` (a results folder, written whole), and its
    3D page (`page`)."""
    t0 = time.perf_counter()
    timer = StageTimer()
    info = scan.recording
    with timer("read"):
        views = read_recorded_views(scan)
    with timer("volume"):
        volume = working_volume(views, settings)
    with timer("pairs"):
        paired = paired_clouds(views, volume, settings)
    footprint = footprint_m(views, volume, settings.two_view.downscale)
    config = pipeline_config(settings, volume, footprint, info.camera_poses_given)
    voxel = config.filter.voxel_size_m
    with timer("table"):
        table = table_of(views, paired, settings)
    inputs = ReconstructionInputs(
        views=paired.views,
        X_FC_nominal=scan.X_FC_nominal,
        config=config,
        remove_points=_keep_hook(views, settings, table),
        eyes_of=lambda index, X_WC: X_WC[:3, 3][None],
    )
    with timer("reconstruct"):
        result = reconstruct_views(inputs)
    with timer("measures"):
        measured = measures(views, paired, result, settings, voxel)
    report = _report(scan, views, paired, volume, table, result, measured, settings, voxel)
    with staged_folder(out, RECONSTRUCTION_MARKER) as staging:
        exports = prepare_exports(result.meshes, settings.mesh_export, settings.primary_surface)
        paths = save_outputs(result, staging, settings.mesh_formats, exports)
        report["outputs"] = {name: p.name for name, p in paths.items()}
        report["reconstruction_stage_s"] = {**timer.seconds, **result.timings_s}
        report["reconstruct_s"] = time.perf_counter() - t0
        report["self_checks"] = self_check_record(report)
        atomic_write_text(staging / "report.json", json.dumps(report, indent=2) + "\n")
        write_recording_summary(report, staging)
        details = summary(result)
        # The marker last: a folder without it is not a result.
        atomic_write_text(
            staging / RECONSTRUCTION_MARKER, yaml_text({"recording": True, **details})
        )
    run = RecordingRun(result, report, Path(out))
    return add_recording_page(run, views, settings) if page else run


def recording_scene(result: ReconstructionResult, views: RecordedViews, settings):
    """model.html's scene of a recording's model: the mesh coloured by its distance to the
    fused measurements (as a scan without truth), the views' frustums; no cell, no arm."""
    from scanner.reconstruct.model_scene import colouring, headline_mesh
    from scanner.reports.model_page_layers import DisplayMesh, ModelScene, ViewFrustum, decimated

    mesh = headline_mesh(result, settings.primary_surface)
    if mesh is None:
        return None
    vertices, triangles = decimated(mesh.vertices, mesh.triangles)
    colours = colouring(vertices, result, None, None)
    return ModelScene(
        mesh=DisplayMesh(vertices, triangles, colours.values_m),
        scale_m=colours.scale_m,
        colour_meaning=f"{mesh.name} mesh: {colours.meaning}",
        signed=colours.signed,
        frustums=tuple(ViewFrustum(X) for X in views.X_WC),
        camera=views.cameras[0],
    )


def add_recording_page(run: RecordingRun, views: RecordedViews, settings) -> RecordingRun:
    """model.html beside the finished results, linked from report.json (a failure to write it
    is a warning: the results are complete without it)."""
    from scanner.reconstruct.model_scene import write_reconstruction_page
    from scanner.reports.model_page import PAGE_NAME

    seconds = write_reconstruction_page(
        run.results_dir, lambda: recording_scene(run.result, views, settings)
    )
    if seconds is None:
        return run
    report = {**run.report, "model_page": PAGE_NAME, "model_page_s": seconds}
    atomic_write_text(run.results_dir / "report.json", json.dumps(report, indent=2) + "\n")
    return RecordingRun(run.result, report, run.results_dir)


def _report(scan, views, paired, volume, table, result, measured, settings, voxel) -> dict:
    info = scan.recording
    pairs = [
        {
            "reference": views.indices[p.reference],
            "other": views.indices[p.other],
            "baseline_mm": round(1e3 * p.baseline_m, 2),
            "angle_deg": round(math.degrees(p.angle_rad), 2),
            "points": len(c.points_C),
            "epipolar_median_px_before": round(c.pose.before.median_px, 3),
            "epipolar_median_px": round(c.pose.after.median_px, 3),
            "pose_refined": c.pose.refined,
            "seconds": round(s, 2),
        }
        for p, c, s in zip(paired.pairs, paired.clouds, paired.seconds, strict=True)
        if p is not None
    ]
    masks = sum(m is not None for m in views.masks)
    return {
        "object": scan.manifest.get("object"),
        "status": "complete",
        "sensor": "one camera, stereo from pairs of its views",
        "recording": {
            **info.to_dict(),
            "masks_used": settings.masks if masks else "none (the recording has none)",
            "handeye": "not run: the recording gave camera poses"
            if info.camera_poses_given
            else ("run" if settings.reconstruction.handeye.enabled else "off"),
        },
        "working_volume": {
            "source": volume.source,
            "centre_m": [round(float(c), 6) for c in volume.centre_W],
            "radius_m": round(float(volume.radius_m), 6),
        },
        "table": None
        if table is None
        else {
            "normal_W": [round(float(c), 6) for c in table.normal_W],
            "offset_m": round(table.offset_m, 6),
            "share": round(table.share, 4),
        },
        "voxel_size_m": voxel,
        "captures_used": len(views.indices),
        "captures_skipped": [],
        "pairs": pairs,
        "pairs_refined": sum(p["pose_refined"] for p in pairs),
        "depth_views": sum(p is None for p in paired.pairs),
        "fused_points": len(result.fused.points_W),
        **measured,
    }


def write_recording_summary(report: dict, out: Path) -> Path:
    """summary.md: what was done with the recording and how well the model agrees with it."""
    rec = report["recording"]
    volume = report["working_volume"]
    lines = [
        f"# Model of the recording {report['object']}",
        "",
        f"- {rec['views']} views ({rec['format']}, {rec['metres_per_unit']:g} m per unit), "
        f"{len(report['pairs'])} pairs of one camera's views"
        + (
            f", {report['depth_views']} views from their own depth images"
            if report["depth_views"]
            else ""
        )
        + f"; masks used: {rec['masks_used']}.",
        f"- Hand-eye correction: {rec['handeye']}.",
        f"- Working volume from {volume['source']}: radius {1e3 * volume['radius_m']:.1f} mm.",
        "- Table: "
        + (
            "none found in the data."
            if report["table"] is None
            else f"found (a plane holding {100 * report['table']['share']:.0f} % of the "
            "points), removed."
        ),
        f"- Pairs whose relative pose was refined from the images: {report['pairs_refined']}.",
        "",
    ]
    s = report.get("silhouette")
    if s:
        where = (
            "views whose masks the model did not use"
            if s["held_out"]
            else "every view (their masks were used: not held out)"
        )
        m, c = s["mesh"], s["fused_cloud"]
        lines += [
            f"## Silhouettes ({len(s['views'])} {where})",
            "",
            f"- Model: IoU {m['iou_median']:.3f} median, {m['iou_worst']:.3f} worst "
            f"(view {m['iou_worst_view']}); mask pixels covered {m['coverage_median']:.3f} "
            f"median, {m['coverage_worst']:.3f} worst.",
            f"- Fused cloud: IoU {c['iou_median']:.3f} median, {c['iou_worst']:.3f} worst; "
            f"covered {c['coverage_median']:.3f} median.",
            "",
        ]
    h = report.get("split_half")
    if h:
        lines += [
            "## Split-half agreement (fused points of even vs odd reference views)",
            "",
            f"- {h['median_mm']} mm median, {h['p90_mm']} mm p90 on the common part "
            f"({100 * h['common_share']:.1f} % of the points within {h['common_radius_mm']} mm).",
            "",
        ]
    path = Path(out) / "summary.md"
    atomic_write_text(path, "\n".join(lines))
    return path


def reconstruct_recording_with(scan: SavedScan, options) -> RecordingRun:
    """`scanner reconstruct` of a recording with the command's options (ReconstructOptions):
    --config is a recording's settings file (RecordingProcessing), --calibration does not apply
    (the recording carries its cameras), the rest as for a scan."""
    from scanner.configs.flags import for_flag
    from scanner.configs.typed_yaml import load_yaml_file
    from scanner.reconstruct.command import _mesh_export
    from scanner.reconstruct.stages import free_reconstruction_dir
    from scanner.scan_dir.results_folder import require_replaceable

    if options.calibration is not None:
        raise ScannerError(
            f"--calibration: {scan.root} is an imported recording, whose views carry their own "
            "cameras and poses; give none"
        )
    settings = (
        load_yaml_file(RecordingProcessing, options.config)
        if options.config is not None
        else RecordingProcessing()
    )
    rec = settings.reconstruction
    if options.no_icp:
        rec = replace(rec, icp=replace(rec.icp, enabled=False))
    if options.no_handeye:
        rec = replace(rec, handeye=replace(rec.handeye, enabled=False))
    settings = replace(
        settings, reconstruction=rec, mesh_export=_mesh_export(settings.mesh_export, options)
    )
    if options.formats is not None:
        formats = tuple("." + f.strip().lstrip(".").lower() for f in options.formats.split(","))
        settings = for_flag("--formats", lambda: replace(settings, mesh_formats=formats))
    if options.masks is not None:
        settings = replace(settings, masks=options.masks)
    if options.volume is not None:
        x, y, z, r = options.volume
        settings = for_flag(
            "--volume", lambda: replace(settings, volume_centre_m=(x, y, z), volume_radius_m=r)
        )
    out = options.out or free_reconstruction_dir(scan.root)
    if options.out is not None:
        require_replaceable(options.out, RECONSTRUCTION_MARKER, options.force, "reconstruction")
    return reconstruct_recording(scan, settings, out)

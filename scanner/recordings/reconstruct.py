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
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.stage_timer import StageTimer
from reconstruction.common.transforms import transform_points
from reconstruction.common.yaml_files import yaml_text
from reconstruction.config import ReconstructionConfig
from reconstruction.outputs import save_outputs, summary
from reconstruction.pipeline import (
    ReconstructionInputs,
    ReconstructionResult,
    reconstruct_views,
)
from reconstruction.registration.filtering import RegionOfInterest
from reconstruction.surfaces.export import prepare_exports
from reconstruction.working_volume.table import TablePlane, above_table, find_table
from reconstruction.working_volume.volume import WorkingVolume
from scanner.recordings.measures import measures
from scanner.recordings.page import add_recording_page
from scanner.recordings.report import recording_report, write_recording_summary
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


def _region_of_interest(volume: WorkingVolume) -> RegionOfInterest:
    """The working volume as the filter's crop: its sphere, or the box the user gave."""
    centre = tuple(map(float, volume.centre_W))
    if volume.half_extent_m is None:
        return RegionOfInterest("sphere", centre, float(volume.radius_m))
    return RegionOfInterest("box", centre, float(volume.radius_m), volume.half_extent_m)


def pipeline_config(
    settings: RecordingProcessing, volume: WorkingVolume, footprint: float, poses_given: bool
) -> ReconstructionConfig:
    """The pipeline's settings for this recording: its volume as the region of interest, grids
    from its pixel footprint, and no hand-eye correction when the camera poses were given."""
    rec = settings.reconstruction
    voxel = settings.voxel_footprints * footprint
    roi = _region_of_interest(volume)
    fused = settings.fused_footprints * footprint
    surfaces = replace(
        rec.surfaces,
        fused_voxel_size_m=fused,
        tsdf_voxel_size_m=fused,
        poisson_max_distance_m=settings.poisson_trim_footprints * footprint,
    )
    handeye = replace(rec.handeye, enabled=rec.handeye.enabled and not poses_given)
    register = rec.icp.enabled and (settings.register_given_poses or not poses_given)
    # A pair's registration is pruned above an inlier RMS of one filter voxel, as the
    # product's own scans have it (1 mm at 1 mm voxels): a recording of coarser pixels keeps
    # its pairs (never a tighter limit than the scans').
    max_rmse = max(rec.icp.max_inlier_rmse_m, voxel)
    return replace(
        rec,
        icp=replace(rec.icp, enabled=register, max_inlier_rmse_m=max_rmse),
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


def _colour_picture(
    result: ReconstructionResult, views: RecordedViews, settings: RecordingProcessing, out: Path
) -> Path | None:
    """The model in the colours of its images, seen from where the cameras stood (None: a
    model without colours)."""
    from scanner.reconstruct.model_scene import headline_mesh
    from scanner.reports.colour_picture import PICTURE_NAME, write_colour_picture

    mesh = headline_mesh(result, settings.primary_surface)
    if mesh is None or mesh.colors is None or not len(mesh.colors):
        return None
    return write_colour_picture(
        mesh.vertices, mesh.triangles, mesh.colors, views.X_WC, out / PICTURE_NAME
    )


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
        source = footprint_m(views, volume, 1.0)
        measured = measures(views, paired, result, settings, voxel, source)
    report = recording_report(scan, views, paired, volume, table, result, measured, settings, voxel)
    with staged_folder(out, RECONSTRUCTION_MARKER) as staging:
        exports = prepare_exports(result.meshes, settings.mesh_export, settings.primary_surface)
        paths = save_outputs(result, staging, settings.mesh_formats, exports)
        report["outputs"] = {name: p.name for name, p in paths.items()}
        with timer("picture"):
            picture = _colour_picture(result, views, settings, staging)
        if picture is not None:
            report["outputs"]["colour_picture"] = picture.name
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
    if page:
        report = add_recording_page(result, report, Path(out), views, settings)
    return RecordingRun(result, report, Path(out))


def _with_volume(settings: RecordingProcessing, options) -> RecordingProcessing:
    """--volume X Y Z R (a sphere) or --box XMIN YMIN ZMIN XMAX YMAX ZMAX, not both."""
    from scanner.configs.flags import for_flag

    if options.volume is not None and options.box is not None:
        raise ScannerError("--box, --volume: give the sphere or the box, not both")
    if options.volume is not None:
        x, y, z, r = map(float, options.volume)
        return for_flag(
            "--volume",
            lambda: replace(
                settings, volume_centre_m=(x, y, z), volume_radius_m=r, volume_box_m=None
            ),
        )
    if options.box is not None:
        box = tuple(map(float, options.box))
        return for_flag(
            "--box",
            lambda: replace(settings, volume_box_m=box, volume_centre_m=None, volume_radius_m=None),
        )
    return settings


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
    settings = _with_volume(settings, options)
    out = options.out or free_reconstruction_dir(scan.root)
    if options.out is not None:
        require_replaceable(options.out, RECONSTRUCTION_MARKER, options.force, "reconstruction")
    return reconstruct_recording(scan, settings, out)

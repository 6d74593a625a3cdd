"""How well a recording's model agrees with the recording, without a reference surface: its
silhouettes against the masks of the views it did not use, and the split-half agreement of the
fused points of the even and the odd reference views (`reconstruction.evaluation`)."""

from __future__ import annotations

import math

from reconstruction.evaluation.silhouette import (
    SilhouetteAgreement,
    cloud_silhouette_agreement,
    silhouette_agreement,
)
from reconstruction.evaluation.split_half import SplitHalf, split_half_agreement
from reconstruction.pipeline import ReconstructionResult
from reconstruction.surfaces.fused import fuse_clouds
from scanner.recordings.settings import RecordingProcessing
from scanner.recordings.views import PairedClouds, RecordedViews, mask_used


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
    source_footprint_m: float,
) -> dict:
    """Silhouettes on the views whose masks the model did not use (all views with masks when
    it used them all: then not held out, and said so), and the split-half agreement of the
    clouds of even and odd reference views at their final poses. voxel_m: the model's point
    spacing (the cloud's splats); source_footprint_m: a source pixel's size on the object,
    which the split-half grid and common radius are set in."""
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
    out["split_half"] = _split_half(paired, result, settings, source_footprint_m)
    return out


def _silhouette_record(a: SilhouetteAgreement, views: RecordedViews, scored) -> dict:
    record = a.summary()
    record["iou_worst_view"] = views.indices[scored[record["iou_worst_view"]]]
    record["coverage_worst_view"] = views.indices[scored[record["coverage_worst_view"]]]
    return record


def _split_half(paired: PairedClouds, result, settings: RecordingProcessing, footprint_m: float):
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
    voxel_m = settings.split_half_voxel_footprints * footprint_m
    common_m = settings.split_half_common_footprints * footprint_m
    even = fuse_clouds(*halves[0], voxel_m)
    odd = fuse_clouds(*halves[1], voxel_m)
    s: SplitHalf = split_half_agreement(even.points_W, odd.points_W, common_m)
    return {
        "median_mm": _mm(s.median_m),
        "p90_mm": _mm(s.p90_m),
        "normal_median_mm": _mm(s.normal_median_m),
        "normal_p90_mm": _mm(s.normal_p90_m),
        "common_share": round(s.common_share, 4),
        "common_radius_mm": round(1e3 * common_m, 4),
        "voxel_mm": round(1e3 * voxel_m, 4),
    }


def _mm(value_m: float) -> float | None:
    return round(1e3 * value_m, 4) if math.isfinite(value_m) else None

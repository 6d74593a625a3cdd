"""Experiments on a recording's split-half agreement: the pair clouds, the per-view filter and the
halves' fusion of `scanner reconstruct` of an imported recording, without the surfaces.

Each run changes one setting (a YAML of RecordingProcessing overrides, or the flags below) and
prints one JSON line: the split-half agreement exactly as the recording's report measures it
(`scanner.recordings.measures`: even and odd reference views fused at one source footprint,
common part within four), the points, and the stage times.

    python scripts/splithalf_experiments.py --scan SCAN_DIR [--views 10-25] [--config FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _subset(views, first: int, last: int):
    """The views first..last (capture order); the first is even so the halves stay the halves."""
    keep = slice(first, last + 1)
    return replace(
        views,
        indices=views.indices[keep],
        images=views.images[keep],
        masks=views.masks[keep],
        cameras=views.cameras[keep],
        X_WC=views.X_WC[keep],
        X_WF=views.X_WF[keep],
        depths=views.depths[keep],
        depth_scales_m=views.depth_scales_m[keep],
    )


def _cleaned(points_W: np.ndarray) -> np.ndarray:
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_W))
    cloud, _ = cloud.remove_statistical_outlier(20, 2.0)
    return np.asarray(cloud.points)


def main() -> None:
    from reconstruction.evaluation.split_half import split_half_agreement
    from reconstruction.registration.filtering import filter_view
    from reconstruction.surfaces.fused import fuse_clouds
    from scanner.configs.typed_yaml import load_yaml_file
    from scanner.recordings.reconstruct import _keep_hook, pipeline_config, table_of
    from scanner.recordings.settings import RecordingProcessing
    from scanner.recordings.views import (
        footprint_m,
        paired_clouds,
        read_recorded_views,
        working_volume,
    )
    from scanner.scan_dir.manifest import open_scan

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scan", type=Path, required=True)
    parser.add_argument("--views", default=None, help="first-last capture positions (all)")
    parser.add_argument("--config", type=Path, default=None, help="RecordingProcessing YAML")
    parser.add_argument("--masks", default="even")
    parser.add_argument("--label", default="")
    parser.add_argument(
        "--half-outliers",
        action="store_true",
        help="diagnostic: each half cleaned as the peer cleans its (20 neighbours, 2 sigma)",
    )
    args = parser.parse_args()

    settings = (
        load_yaml_file(RecordingProcessing, args.config) if args.config else RecordingProcessing()
    )
    settings = replace(settings, masks=args.masks)
    scan = open_scan(args.scan)
    views = read_recorded_views(scan)
    if args.views:
        first, last = (int(v) for v in args.views.split("-"))
        views = _subset(views, first, last)
    t_read = time.perf_counter()
    volume = working_volume(views, settings)
    paired = paired_clouds(views, volume, settings)
    t_pairs = time.perf_counter()
    footprint = footprint_m(views, volume, settings.two_view.downscale)
    config = pipeline_config(settings, volume, footprint, True)
    table = table_of(views, paired, settings)
    hook = _keep_hook(views, settings, table)

    def one(k: int):
        v = paired.views[k]
        X_WC = views.X_WC[paired.references[k]]
        return filter_view(k, v.points_C, v.colors, X_WC, config.filter, hook)

    # Two at a time, as the pipeline's filter_views.
    with ThreadPoolExecutor(max_workers=2) as pool:
        filtered = list(pool.map(one, range(len(paired.views))))
    t_filter = time.perf_counter()
    source = footprint_m(views, volume, 1.0)
    halves = {0: ([], []), 1: ([], [])}
    for k, cloud in enumerate(filtered):
        if len(cloud) < config.filter.min_points:
            continue
        i = paired.references[k]
        halves[i % 2][0].append(cloud)
        halves[i % 2][1].append(views.X_WC[i])
    voxel_m = settings.split_half_voxel_footprints * source
    even = fuse_clouds(*halves[0], voxel_m)
    odd = fuse_clouds(*halves[1], voxel_m)
    even_W, odd_W = even.points_W, odd.points_W
    if args.half_outliers:
        even_W, odd_W = _cleaned(even_W), _cleaned(odd_W)
    common_m = settings.split_half_common_footprints * source
    s = split_half_agreement(even_W, odd_W, common_m)
    t_end = time.perf_counter()
    refined = sum(bool(getattr(c, "refined", False)) for c in paired.clouds)
    epi = [c.pose.before.median_px for c in paired.clouds if hasattr(c, "pose")]
    print(
        json.dumps(
            {
                "label": args.label,
                "views": len(views.indices),
                "pairs": len(paired.clouds),
                "refined": refined,
                "epipolar_median_px": round(float(np.nanmedian(epi)), 3) if epi else None,
                "raw_points": int(sum(len(v.points_C) for v in paired.views)),
                "even_points": len(even_W),
                "odd_points": len(odd_W),
                "median_mm": round(1e3 * s.median_m, 4),
                "p90_mm": round(1e3 * s.p90_m, 4),
                "common_share": round(s.common_share, 4),
                "pairs_s": round(t_pairs - t_read, 1),
                "filter_s": round(t_filter - t_pairs, 1),
                "measure_s": round(t_end - t_filter, 1),
                # CPU seconds of all threads: comparable across runs on a shared machine.
                "cpu_s": round(time.process_time(), 1),
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main()

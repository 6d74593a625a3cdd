"""Benchmark: the product's default reconstruction beside the pipeline of Open3D's
reconstruction system tutorial (peer_pipeline.py), on the same saved scans.

Each object of --objects (default bunny and vase, largest extent 0.2 m) is scanned once
(--views views, one hanging, the default error model: the mount 3 mm / 1 deg off its nominal
X_FC, encoder offsets, sensor noise; seed 0), captures only; --scan-root keeps and reuses them.
Then, in this one process:

- shared: the product's stereo stage (`gather_views`: SGBM clouds and depth maps of every
  capture at the scan's nominal X_FC), done once; both pipelines start from its output.
- product: `reconstruct_views` with the scan's own processing settings, as
  `scanner reconstruct SCAN_DIR` runs it (filter, coarse hand-eye, ICP + pose graph, hand-eye
  correction, fused cloud, Poisson and TSDF meshes, coverage); its primary surface is measured.
- peer: the product's filter on the same views (`filter_views`, at the nominal X_FC), then the
  tutorial's pairwise multiscale ICP from the robot poses at the nominal X_FC, pose graph,
  TSDF mesh of the product's depth maps (peer_pipeline.py says what was followed and changed).

Both meshes are measured by the product's evaluation against the true surface in the world
frame, on the same truth samples: observed Chamfer (the mean of both directions' mean
distances, on the truth the true views saw) and accuracy p90 (result to truth). `cpu_s`: CPU
seconds of this process and its children (time.process_time() plus the finished children's
rusage: the Poisson solver's process) over each pipeline, the shared stereo stage added to
both; `wall_s` likewise. The evaluation and the writing of results files are in neither.
`ratios`: product / peer per object, and over all objects (sums of CPU, mean of Chamfer
ratios). Targets: product observed Chamfer <= 0.5 x the peer's with no more CPU seconds.

Prints one JSON line (progress on stderr).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
from benchmark_data import MESHES, require
from peer_pipeline import PeerConfig, peer_reconstruct, peer_views, pose_change, tutorial_scaled

from reconstruction.common.transforms import invert, transform_points
from reconstruction.evaluation.metrics import TriangleSurface, evaluate_surface, handeye_error
from reconstruction.evaluation.reference_alignment import align_reference
from reconstruction.pipeline import ReconstructionInputs, reconstruct_views
from reconstruction.registration.filtering import filter_views
from scanner.configs.scan import ScanConfig, with_overrides
from scanner.reconstruct.evaluation import observed_samples, to_first_hanging, truth_metrics
from scanner.reconstruct.scan_views import Gathered, gather_views, with_roi_centre
from scanner.scan.run import run_scan
from scanner.scan_dir.manifest import SavedScan, open_scan

# Object name -> the scan's object spec (a benchmark mesh file, or a built-in object).
OBJECTS = {
    "bunny": "stanford-bunny.obj",
    "fandisk": "fandisk.obj",
    "spot": "spot.obj",
    "teapot": "teapot.obj",
    "vase": None,  # built in
}
SIZE_M = 0.2
KEYS = ("chamfer_observed_mm", "accuracy_p90_mm", "completeness_observed_2mm", "chamfer_mm")


def _log(message: str) -> None:
    print(f"bench_peer: {message}", file=sys.stderr, flush=True)


def cpu_s() -> float:
    """This process's CPU time and its finished children's (the Poisson solver)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


@contextmanager
def measured(into: dict, key: str):
    """CPU and wall seconds of the block, into `into[key]` as (cpu_s, wall_s)."""
    cpu0, wall0 = cpu_s(), time.perf_counter()
    yield
    into[key] = (cpu_s() - cpu0, time.perf_counter() - wall0)


def scan_of(name: str, scan_dir: Path, views: int) -> Path:
    """A captured one-hanging scan of the object at 0.2 m, seed 0 (reused when there)."""
    if not (scan_dir / "scan.yaml").is_file():
        spec = OBJECTS[name]
        config = with_overrides(
            ScanConfig(),
            object_spec=str(require(MESHES / spec, "bench_peer")) if spec else name,
            size_m=SIZE_M,
            views=views,
            seed=0,
            hangings=1,
        )
        _log(f"scanning {name} ({views} views) into {scan_dir}")
        run_scan(replace(config, reconstruct=False), scan_dir)
    return scan_dir


def run_product(scan: SavedScan, gathered: Gathered, times: dict):
    """`reconstruct_views` as `scanner reconstruct` calls it with the scan's own settings."""
    processing = scan.config.processing
    config = with_roi_centre(processing.reconstruction, np.array(scan.config.scan_center_m))
    with measured(times, "product"):
        inputs = ReconstructionInputs(
            views=gathered.views,
            X_FC_nominal=scan.X_FC_nominal,
            config=config,
            remove_points=gathered.remove,
            eyes_of=lambda index, X_WC: scan.camera_model.eye_centres_W(X_WC),
            fixtures=gathered.fixtures,
        )
        result = reconstruct_views(inputs)
    return result


def run_peer(scan: SavedScan, gathered: Gathered, peer: PeerConfig, times: dict):
    processing = scan.config.processing
    config = with_roi_centre(processing.reconstruction, np.array(scan.config.scan_center_m))
    with measured(times, "peer"):
        views, clouds, _ = filter_views(
            gathered.views, scan.X_FC_nominal, config.filter, gathered.remove
        )
        prepared = peer_views(views, clouds, scan.X_FC_nominal, config.filter.roi, gathered.remove)
        result = peer_reconstruct(prepared, peer)
    return prepared, result


def aligned_chamfer_mm(vertices, triangles, surface, samples, n_samples: int) -> float:
    """The observed Chamfer after the best rigid fit of the truth onto the mesh (the
    product's reference alignment, started as given): the shape's error without the error of
    where the model stands in W (a mount error no view-to-view registration can see)."""
    fit = align_reference(vertices, surface)
    moved = TriangleSurface(transform_points(invert(fit.X_MR), vertices), triangles)
    metrics = evaluate_surface(
        None, surface, result_mesh=moved, n_samples=n_samples, truth_samples=samples
    )
    return metrics["chamfer_observed_mm"]


def _rounded(d: dict) -> dict:
    return {k: round(d[k], 4) for k in KEYS if k in d}


def bench_object(name: str, scan_dir: Path, peer: PeerConfig) -> dict:
    scan = open_scan(scan_dir)
    processing = scan.config.processing
    times: dict = {}
    _log(f"{name}: stereo")
    with measured(times, "stereo"):
        gathered = gather_views([scan], processing)
    _log(f"{name}: product")
    product = run_product(scan, gathered, times)
    _log(f"{name}: peer")
    prepared, peer_result = run_peer(scan, gathered, peer, times)

    _log(f"{name}: evaluation")
    to_first = to_first_hanging(gathered)
    samples = observed_samples(gathered, processing, to_first)
    product_metrics = truth_metrics(product, gathered, processing, to_first, samples)
    truth, surface, _ = gathered.truths[0]
    peer_metrics = evaluate_surface(
        None,
        surface,
        result_mesh=TriangleSurface(peer_result.vertices, peer_result.triangles),
        n_samples=processing.metric_samples,
        truth_samples=samples,
    )
    primary = product.meshes[processing.primary_surface]
    aligned = {
        "product": aligned_chamfer_mm(
            primary.vertices, primary.triangles, surface, samples, processing.metric_samples
        ),
        "peer": aligned_chamfer_mm(
            peer_result.vertices,
            peer_result.triangles,
            surface,
            samples,
            processing.metric_samples,
        ),
    }
    # How far the peer's poses moved from the robot's, and how far the nominal mount is off.
    moves = [pose_change(v.X_WC_start, X) for v, X in zip(prepared, peer_result.X_WC)]
    stereo_cpu, stereo_wall = times["stereo"]
    out = {"views": len(gathered.views)}
    for key, metrics in (("product", product_metrics), ("peer", peer_metrics)):
        cpu, wall = times[key]
        out[key] = {
            **_rounded(metrics),
            "cpu_s": round(stereo_cpu + cpu, 1),
            "wall_s": round(stereo_wall + wall, 1),
            "chamfer_observed_rigidly_aligned_mm": round(aligned[key], 4),
        }
    out["product"]["surface"] = processing.primary_surface
    out["product"]["handeye_error_mm"] = round(product_metrics["handeye_error_mm"], 3)
    out["peer"].update(
        surface="tsdf",
        pairs_tried=peer_result.pairs_tried,
        edges=len(peer_result.edges),
        edges_after_pruning=peer_result.edges_kept,
        pose_change_max_mm=round(1e3 * max(m[0] for m in moves), 2),
        pose_change_max_deg=round(math.degrees(max(m[1] for m in moves)), 3),
        stage_s={k: round(v, 1) for k, v in peer_result.stage_s.items()},
        handeye_error_mm=round(handeye_error(scan.X_FC_nominal, truth.X_FC)["handeye_error_mm"], 3),
    )
    out["stereo_cpu_s"] = round(stereo_cpu, 1)
    out["ratios"] = {
        "product_chamfer / peer_chamfer": round(
            out["product"]["chamfer_observed_mm"] / out["peer"]["chamfer_observed_mm"], 3
        ),
        "product_cpu_s / peer_cpu_s": round(out["product"]["cpu_s"] / out["peer"]["cpu_s"], 3),
    }
    _log(f"{name}: {json.dumps(out)}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--objects",
        default="bunny,vase",
        help=f"comma-separated from {', '.join(OBJECTS)} (default bunny,vase)",
    )
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument(
        "--scan-root", type=Path, default=None, help="keep the scans here and reuse them"
    )
    args = parser.parse_args()
    names = [n.strip() for n in args.objects.split(",") if n.strip()]
    unknown = [n for n in names if n not in OBJECTS]
    if unknown:
        sys.exit(f"bench_peer: unknown object(s) {unknown}; valid: {list(OBJECTS)}")
    peer = tutorial_scaled(SIZE_M)
    out: dict = {
        "views": args.views,
        "shared_views": "the product's SGBM stereo clouds (filtered) and depth maps",
        "peer_X_FC_start": "the scan's nominal X_FC (manifest X_FC_nominal)",
        "peer_voxel_size_mm": round(1e3 * peer.voxel_size_m, 3),
        "peer_tsdf_voxel_mm": round(1e3 * peer.tsdf_voxel_size_m, 3),
        "peer_sdf_trunc_mm": round(1e3 * peer.sdf_trunc_m, 3),
        "cores": len(os.sched_getaffinity(0)),
        "load_avg_1min_start": round(os.getloadavg()[0], 2),
    }
    wall0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.scan_root or Path(tmp) / "scans"
        for name in names:
            out[name] = bench_object(name, scan_of(name, root / name, args.views), peer)
    cases = [out[n] for n in names]
    chamfer_ratios = [c["ratios"]["product_chamfer / peer_chamfer"] for c in cases]
    product_cpu = sum(c["product"]["cpu_s"] for c in cases)
    peer_cpu = sum(c["peer"]["cpu_s"] for c in cases)
    out["ratios"] = {
        "product_chamfer / peer_chamfer_mean": round(float(np.mean(chamfer_ratios)), 3),
        "product_cpu_s / peer_cpu_s": round(product_cpu / peer_cpu, 3),
    }
    out["targets_met"] = {
        "chamfer_half_of_peer": all(r <= 0.5 for r in chamfer_ratios),
        "cpu_not_above_peer": all(c["ratios"]["product_cpu_s / peer_cpu_s"] <= 1.0 for c in cases),
    }
    out["load_avg_1min_end"] = round(os.getloadavg()[0], 2)
    out["wall_s"] = round(time.perf_counter() - wall0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()

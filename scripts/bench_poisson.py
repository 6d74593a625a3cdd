"""Benchmark: Poisson solvers side by side on the fused clouds of kept scans.

For each scan directory (a simulated scan reconstructed once, e.g. `bench_scan.py --keep DIR`)
reads results/fused_cloud.ply, solves it with each candidate, trims the solution as the
pipeline does (`poisson_mesh`, and `poisson_closed_mesh` for two hangings or more) and
measures it against the simulator's truth (the observed Chamfer of the report). Candidates:
`open3d` (Open3D's screened Poisson, one thread, the configured depth), `open3d_thinned` (the
cloud first averaged over voxels of 1, 1.5 or 2 of the octree's finest cells),
`open3d_adaptive` (the depth chosen from the object's size and the fused voxel,
`poisson_depth_for`), and, when pymeshlab imports, `meshlab_t1` / `meshlab_t2` (PoissonRecon
through pymeshlab, one and two threads). Each candidate is solved twice (once with --once):
`identical` says whether the two meshes are equal. Prints one JSON line per scan: per
candidate wall_s, cpu_s, vertices, chamfer_observed_mm (and the closed surface's whole-object
Chamfer where it is built).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import open3d as o3d

from reconstruction.evaluation.metrics import SurfaceSamples, TriangleSurface, evaluate_surface
from reconstruction.registration.filtering import RegionOfInterest
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.fused import FusedCloud
from reconstruction.surfaces.meshes import SurfaceInput
from reconstruction.surfaces.poisson import poisson_closed_mesh, poisson_mesh
from reconstruction.surfaces.poisson_solver import PoissonSolution, solve_poisson
from scanner.configs.scan import ProcessingConfig
from scanner.reconstruct.evaluation import observed_samples, to_first_hanging
from scanner.reconstruct.scan_views import Gathered, load_truth_of
from scanner.scan_dir.manifest import open_scan

# Open3D's (and PoissonRecon's) octree spans the points' largest extent times this.
POISSON_SCALE = 1.1


def poisson_depth_for(points_W: np.ndarray, spacing_m: float) -> int:
    """The coarsest octree depth whose finest cells are no larger than the data's spacing
    (`spacing_m`, the fused voxel): finer cells add unknowns the data cannot constrain."""
    extent_m = float(np.max(np.ptp(points_W, axis=0))) if len(points_W) else 0.0
    return max(1, int(np.ceil(np.log2(max(POISSON_SCALE * extent_m / spacing_m, 2.0)))))


def _fused(scan_dir: Path) -> FusedCloud:
    pc = o3d.io.read_point_cloud(str(scan_dir / "results" / "fused_cloud.ply"))
    return FusedCloud(
        np.asarray(pc.points),
        np.clip(np.round(np.asarray(pc.colors) * 255), 0, 255).astype(np.uint8),
        np.asarray(pc.normals),
    )


def _truth(scan_dir: Path, processing: ProcessingConfig):
    """The true surface, its samples and which of them the true views saw (no stereo: only
    the captures' joints are read; the samples kept in the scan's results for the next run)."""
    scan = open_scan(scan_dir)
    kept = scan_dir / "results" / "bench_poisson_truth.npz"
    if kept.is_file():
        with np.load(kept) as f:
            samples = SurfaceSamples(f["points"], f["normals"])
            return load_truth_of(scan_dir)[1], (samples, f["observed"])
    indices = scan.store.captured_indices()
    joints = {i: scan.store.read_capture(i).q_rad for i in indices}
    gathered = Gathered(
        views=[],
        skipped=[],
        joints=joints,
        hangings=[list(h) for h in scan.hangings],
        scan_of=dict.fromkeys(indices, 0),
        truths=[load_truth_of(scan_dir)],
        remove=None,
        robots=[scan.config.robot],
    )
    to_first = to_first_hanging(gathered)
    samples, observed = observed_samples(gathered, processing, to_first)
    np.savez(kept, points=samples.points, normals=samples.normals, observed=observed)
    return gathered.truths[0][1], (samples, observed)


def _open3d_thinned(fused: FusedCloud, depth: int, cells: float = 1.0) -> PoissonSolution:
    """The cloud averaged over voxels of `cells` times the octree's finest cell first."""
    extent = float(np.max(fused.points_W.max(0) - fused.points_W.min(0)))
    cell_m = cells * POISSON_SCALE * extent / 2**depth
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(fused.points_W))
    pc.normals = o3d.utility.Vector3dVector(fused.normals_W)
    pc.colors = o3d.utility.Vector3dVector(fused.colors / 255.0)
    pc = pc.voxel_down_sample(cell_m)
    n = np.asarray(pc.normals)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    colors = np.round(np.asarray(pc.colors) * 255).astype(np.uint8)
    return solve_poisson(np.asarray(pc.points), n, colors, depth)


def _meshlab(fused: FusedCloud, depth: int, threads: int) -> PoissonSolution:
    import pymeshlab

    rgba = np.hstack([fused.colors / 255.0, np.ones((len(fused), 1))])
    ms = pymeshlab.MeshSet()
    ms.add_mesh(
        pymeshlab.Mesh(
            vertex_matrix=fused.points_W, v_normals_matrix=fused.normals_W, v_color_matrix=rgba
        )
    )
    ms.generate_surface_reconstruction_screened_poisson(depth=depth, threads=threads)
    m = ms.current_mesh()
    return PoissonSolution(
        m.vertex_matrix().copy(),
        m.face_matrix().astype(np.int32),
        m.vertex_color_matrix()[:, :3].copy(),
        m.vertex_scalar_array().copy(),
    )


def _candidates(config: SurfaceConfig, fused: FusedCloud) -> dict:
    depth = config.poisson_depth
    adaptive = poisson_depth_for(fused.points_W, config.fused_voxel_size_m)
    out = {
        "open3d": lambda: solve_poisson(fused.points_W, fused.normals_W, fused.colors, depth),
        "open3d_thinned": lambda: _open3d_thinned(fused, depth),
        "open3d_thinned_x1.5": lambda: _open3d_thinned(fused, depth, 1.5),
        "open3d_thinned_x2": lambda: _open3d_thinned(fused, depth, 2.0),
        f"open3d_adaptive_d{adaptive}": lambda: solve_poisson(
            fused.points_W, fused.normals_W, fused.colors, adaptive
        ),
    }
    try:
        import pymeshlab  # noqa: F401
    except ImportError:
        return out
    out["meshlab_t1"] = lambda: _meshlab(fused, depth, 1)
    out["meshlab_t2"] = lambda: _meshlab(fused, depth, 2)
    return out


def _measure(solve, fused, config, truth, samples, closed: bool, repeats: int) -> dict:
    runs = []
    for _ in range(repeats):
        wall0, cpu0 = time.perf_counter(), time.process_time()
        s = solve()
        runs.append((s, time.perf_counter() - wall0, time.process_time() - cpu0))
    (s, wall_s, cpu_s), (again, _, _) = runs[0], runs[-1]
    identical = s.vertices.shape == again.vertices.shape and np.array_equal(
        s.vertices, again.vertices
    )
    inputs = SurfaceInput(fused, (), RegionOfInterest(shape="none"), None)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(s.vertices), o3d.utility.Vector3iVector(s.triangles)
    )
    inputs.shared["poisson"] = (mesh, s.density)
    given = {"n_samples": len(samples[0].points), "truth_samples": samples}
    trimmed = poisson_mesh(inputs, config)
    metrics = evaluate_surface(
        None, truth, TriangleSurface(trimmed.vertices, trimmed.triangles), **given
    )
    out = {
        "wall_s": round(wall_s, 2),
        "cpu_s": round(cpu_s, 2),
        "vertices": len(s.vertices),
        "identical": bool(identical) if repeats > 1 else None,
        "chamfer_observed_mm": round(metrics["chamfer_observed_mm"], 4),
    }
    if closed:
        whole = poisson_closed_mesh(inputs, config)
        m = evaluate_surface(None, truth, TriangleSurface(whole.vertices, whole.triangles), **given)
        out["closed_chamfer_mm"] = round(m["chamfer_mm"], 4)
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("scans", type=Path, nargs="+", help="reconstructed simulated scans")
    parser.add_argument("--only", help="comma-separated candidate names (default: all)")
    parser.add_argument(
        "--once", action="store_true", help="solve each candidate once (no determinism check)"
    )
    args = parser.parse_args()
    processing = ProcessingConfig()
    config = processing.reconstruction.surfaces
    for scan_dir in args.scans:
        fused = _fused(scan_dir)
        truth, samples = _truth(scan_dir, processing)
        closed = len(open_scan(scan_dir).hangings) > 1
        extent = fused.points_W.max(0) - fused.points_W.min(0)
        out: dict = {
            "scan": str(scan_dir),
            "points": len(fused),
            "extent_m": extent.round(4).tolist(),
        }
        only = set(args.only.split(",")) if args.only else None
        for name, solve in _candidates(config, fused).items():
            if only is None or name.split("_d")[0] in only or name in only:
                out[name] = _measure(
                    solve, fused, config, truth, samples, closed, 1 if args.once else 2
                )
                print(name, out[name], flush=True)
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()

"""Open3D's screened Poisson solve, run in a process of its own.

Open3D holds Python's GIL for the whole solve (12 s at depth 9 on a 24-view scan), so in a
thread it stalls everything else in Python, the TSDF fusion beside it included. A child
interpreter (`python -m reconstruction.poisson_solver IN OUT`) solves while this process goes
on; arrays travel through .npz files. If the child cannot run, the solve happens here.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

log = logging.getLogger("scanner.reconstruct")


@dataclass(frozen=True, eq=False)
class PoissonSolution:
    """The untrimmed surface: vertices (V, 3) m, triangles (M, 3), vertex colours (V, 3) in
    0-1 (empty without colours), and Poisson's sample density per vertex (V,)."""

    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray
    density: np.ndarray


def solve_poisson(
    points: np.ndarray, normals: np.ndarray, colors: np.ndarray, depth: int
) -> PoissonSolution:
    """On one thread: the multi-threaded solver sums in a varying order, so two runs on the
    same captures would give (slightly) different meshes; on two cores it was not faster
    anyway (9.8 s against 11.7 s)."""
    import open3d as o3d

    from reconstruction.filtering import o3d_cloud

    pc = o3d_cloud(points, normals, colors)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pc, depth=depth, n_threads=1
        )
    return PoissonSolution(
        np.asarray(mesh.vertices),
        np.asarray(mesh.triangles),
        np.asarray(mesh.vertex_colors),
        np.asarray(density),
    )


def solve_poisson_apart(
    points: np.ndarray, normals: np.ndarray, colors: np.ndarray, depth: int
) -> PoissonSolution:
    """`solve_poisson` in a child process (the same result), or here when that fails."""
    with tempfile.TemporaryDirectory(prefix="poisson-") as tmp:
        given, solved = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(given, points=points, normals=normals, colors=colors, depth=depth)
        root = str(Path(__file__).resolve().parents[1])
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]),
        }
        run = subprocess.run(
            [sys.executable, "-m", "reconstruction.poisson_solver", str(given), str(solved)],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
        if run.returncode == 0 and solved.is_file():
            with np.load(solved) as f:
                return PoissonSolution(f["vertices"], f["triangles"], f["colors"], f["density"])
        log.warning(
            "Poisson solver process failed (exit %d: %s); solving in this process",
            run.returncode,
            run.stderr.strip().splitlines()[-1:] or "no message",
        )
    return solve_poisson(points, normals, colors, depth)


def _main(given: str, solved: str) -> None:
    with np.load(given) as f:
        s = solve_poisson(f["points"], f["normals"], f["colors"], int(f["depth"]))
    np.savez(solved, vertices=s.vertices, triangles=s.triangles, colors=s.colors, density=s.density)


if __name__ == "__main__":
    _main(*sys.argv[1:3])

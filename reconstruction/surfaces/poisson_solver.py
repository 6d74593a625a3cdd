"""Open3D's screened Poisson solve, run in a process of its own.

Open3D holds Python's GIL for the whole solve (12 s at depth 9 on a 24-view scan), so in a
thread it stalls everything else in Python, the TSDF fusion beside it included. A child
interpreter (`python -m reconstruction.surfaces.poisson_solver`) solves while this process goes on:
it is started early (`start_solver`, while registration runs, so its 1.5 s of imports are
hidden), then reads the paths of an input and an output .npz from its stdin. If the child
cannot run, the solve happens here.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

log = logging.getLogger("scanner.reconstruct.stages")


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

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    pc.normals = o3d.utility.Vector3dVector(np.asarray(normals, np.float64))
    if len(colors):
        pc.colors = o3d.utility.Vector3dVector(np.asarray(colors, np.float64) / 255.0)
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


_lock = threading.Lock()
_waiting: subprocess.Popen | None = None  # a started child that has not been given work


def _spawn() -> subprocess.Popen:
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen(
        [sys.executable, "-m", "reconstruction.surfaces.poisson_solver"],
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def start_solver() -> None:
    """Start a child now so that it is ready when `solve_poisson_apart` needs it (at most one
    waits; an unused one exits when this process closes its stdin at exit)."""
    global _waiting
    with _lock:
        if _waiting is None or _waiting.poll() is not None:
            try:
                _waiting = _spawn()
            except OSError as e:
                log.warning("could not start the Poisson solver process: %s", e)


def _take_solver() -> subprocess.Popen:
    global _waiting
    with _lock:
        child, _waiting = _waiting, None
    if child is None or child.poll() is not None:
        child = _spawn()
    return child


def solve_poisson_apart(
    points: np.ndarray, normals: np.ndarray, colors: np.ndarray, depth: int
) -> PoissonSolution:
    """`solve_poisson` in a child process (the same result), or here when that fails.
    `colors`: uint8 (N, 3) or empty."""
    with tempfile.TemporaryDirectory(prefix="poisson-") as tmp:
        given, solved = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(given, points=points, normals=normals, colors=colors, depth=depth)
        try:
            child = _take_solver()
            _, err = child.communicate(f"{given}\n{solved}\n")
            code = child.returncode
        except OSError as e:
            code, err = -1, str(e)
        if code == 0 and solved.is_file():
            with np.load(solved) as f:
                return PoissonSolution(f["vertices"], f["triangles"], f["colors"], f["density"])
        log.warning(
            "Poisson solver process failed (exit %d: %s); solving in this process",
            code,
            (err or "").strip().splitlines()[-1:] or "no message",
        )
    return solve_poisson(points, normals, colors, depth)


def _serve() -> None:
    """The child: import what the solve needs, then wait for the two paths on stdin (none:
    the parent did not need it, exit)."""
    import open3d  # noqa: F401  (the slow import, done before the work arrives)

    given, solved = sys.stdin.readline().strip(), sys.stdin.readline().strip()
    if not given or not solved:
        return
    with np.load(given) as f:
        s = solve_poisson(f["points"], f["normals"], f["colors"], int(f["depth"]))
    np.savez(solved, vertices=s.vertices, triangles=s.triangles, colors=s.colors, density=s.density)


if __name__ == "__main__":
    _serve()

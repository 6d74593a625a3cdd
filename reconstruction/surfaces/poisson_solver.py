"""Open3D's screened Poisson solve, run in a process of its own.

Open3D holds Python's GIL for the whole solve (12 s at depth 9 on a 24-view scan), so in a
thread it stalls everything else in Python, the TSDF fusion beside it included. A child
interpreter (`python -m reconstruction.surfaces.poisson_solver`) solves while this process goes on:
it is started early (`start_solver`, while registration runs, so its imports are hidden), then
reads the paths of an input and an output .npz from its stdin, one solve after another. If the
child cannot run, the solve happens here.
"""

from __future__ import annotations

import atexit
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

log = logging.getLogger("scanner.reconstruct.stages")

# Open3D's own default for the solve's cube over the data's bounding cube.
DEFAULT_SCALE = 1.1


@dataclass(frozen=True, eq=False)
class PoissonSolution:
    """The untrimmed surface: vertices (V, 3) m, triangles (M, 3), vertex colours (V, 3) in
    0-1 (empty without colours), and Poisson's sample density per vertex (V,)."""

    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray
    density: np.ndarray


def solve_poisson(
    points: np.ndarray,
    normals: np.ndarray,
    colors: np.ndarray,
    depth: int,
    scale: float = DEFAULT_SCALE,
) -> PoissonSolution:
    """On one thread: the multi-threaded solver sums in a varying order, so two runs on the
    same captures would give (slightly) different meshes; on two cores it was not faster
    anyway (9.8 s against 11.7 s). `scale`: the solve's cube over the data's bounding cube
    (Open3D's default 1.1; larger lets a closed surface close inside it)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    pc.normals = o3d.utility.Vector3dVector(np.asarray(normals, np.float64))
    if len(colors):
        pc.colors = o3d.utility.Vector3dVector(np.asarray(colors, np.float64) / 255.0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pc, depth=depth, scale=scale, n_threads=1
        )
    return PoissonSolution(
        np.asarray(mesh.vertices),
        np.asarray(mesh.triangles),
        np.asarray(mesh.vertex_colors),
        np.asarray(density),
    )


_lock = threading.Lock()
# Started children with nothing to do. A child serves one solve after another (the 0.8 s of
# importing Open3D is paid once per process, not once per surface); two solves at the same time
# (a hanging's surface beside the closed one) each get their own.
_idle: list[subprocess.Popen] = []
_MAX_IDLE = 2


def _spawn() -> subprocess.Popen:
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}
    # stderr is not read while the child lives (a full pipe would stall it): the child reports
    # a failed solve on stdout, and a child that died is answered by solving here.
    return subprocess.Popen(
        [sys.executable, "-m", "reconstruction.surfaces.poisson_solver"],
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )


def start_solver(count: int = 1) -> None:
    """Start children now so that `count` are ready when `solve_poisson_apart` needs them
    (fewer if some already wait; at most the idle limit). A waiting child exits when this
    process exits (its stdin closes)."""
    with _lock:
        _idle[:] = [c for c in _idle if c.poll() is None]
        while len(_idle) < min(count, _MAX_IDLE):
            try:
                _idle.append(_spawn())
            except OSError as e:
                log.warning("could not start the Poisson solver process: %s", e)
                return


def _take_solver() -> subprocess.Popen:
    with _lock:
        while _idle:
            child = _idle.pop()
            if child.poll() is None:
                return child
    return _spawn()


def _give_back(child: subprocess.Popen) -> None:
    with _lock:
        if len(_idle) < _MAX_IDLE:
            _idle.append(child)
            return
    _close(child)


def _close(child: subprocess.Popen) -> None:
    try:
        child.stdin.close()
        child.wait(timeout=5)
    except (OSError, subprocess.TimeoutExpired):
        child.kill()
        child.wait()


@atexit.register
def _close_idle() -> None:
    with _lock:
        children, _idle[:] = list(_idle), []
    for child in children:
        _close(child)


def solve_poisson_apart(
    points: np.ndarray,
    normals: np.ndarray,
    colors: np.ndarray,
    depth: int,
    scale: float = DEFAULT_SCALE,
) -> PoissonSolution:
    """`solve_poisson` in a child process (the same result), or here when that fails.
    `colors`: uint8 (N, 3) or empty."""
    with tempfile.TemporaryDirectory(prefix="poisson-") as tmp:
        given, solved = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(given, points=points, normals=normals, colors=colors, depth=depth, scale=scale)
        child = None
        try:
            child = _take_solver()
            child.stdin.write(f"{given}\n{solved}\n")
            child.stdin.flush()
            answer = child.stdout.readline().strip()
        except OSError as e:
            answer = f"error: {e}"
        if answer == "ok" and solved.is_file():
            _give_back(child)
            with np.load(solved) as f:
                return PoissonSolution(f["vertices"], f["triangles"], f["colors"], f["density"])
        if child is not None:
            child.kill()
            child.wait()
        log.warning(
            "Poisson solver process failed (%s); solving in this process",
            answer or f"it exited with {child.returncode if child else 'no process'}",
        )
    return solve_poisson(points, normals, colors, depth, scale)


def _serve() -> None:
    """The child: import what the solve needs, then solve each pair of paths read from stdin
    (input, output), answering `ok` or `error: ...` on stdout; exit when stdin closes.

    The parent removes each request's folder once it has read the answer. A parent that was
    killed (SIGKILL, out of memory) never does: the child removes the last request's folder
    when it finds its parent gone, so a killed scan leaves no solve behind in the temporary
    directory."""
    from reconstruction.common.memory import keep_freed_memory

    keep_freed_memory()  # also when the parent did not: its solves are the largest arrays
    import open3d  # noqa: F401  (the slow import, done before the work arrives)

    last = None
    try:
        while True:
            given, solved = sys.stdin.readline().strip(), sys.stdin.readline().strip()
            if not given or not solved:
                return
            last = Path(given).parent
            print(_solve_files(given, solved), flush=True)
    except BrokenPipeError:  # the parent is gone: nobody reads the answer
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # exit quietly
    finally:
        if last is not None:
            shutil.rmtree(last, ignore_errors=True)  # already gone when the parent read it


def _solve_files(given: str, solved: str) -> str:
    """One request: the solve of the input .npz written to the output .npz; the answer line."""
    try:
        with np.load(given) as f:
            s = solve_poisson(
                f["points"], f["normals"], f["colors"], int(f["depth"]), float(f["scale"])
            )
        np.savez(
            solved, vertices=s.vertices, triangles=s.triangles, colors=s.colors, density=s.density
        )
        return "ok"
    except Exception as e:  # noqa: BLE001  (reported to the parent, which solves itself)
        return f"error: {type(e).__name__}: {e}".replace("\n", " ")


if __name__ == "__main__":
    _serve()

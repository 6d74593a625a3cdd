"""The Poisson solve in a child process: the same surface as in this process, one child serving
solve after solve, and a child that died or failed answered by solving here."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.surfaces import poisson_solver as ps


def _sphere(n: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    colors = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    return 0.05 * normals + [0.4, 0.0, 1.0], normals, colors


@pytest.fixture
def no_children():
    ps._close_idle()
    yield
    ps._close_idle()


def test_the_child_solves_as_this_process_would_and_serves_the_next_solve(no_children):
    points, normals, colors = _sphere()
    here = ps.solve_poisson(points, normals, colors, 5)
    ps.start_solver()
    (child,) = ps._idle
    first = ps.solve_poisson_apart(points, normals, colors, 5)
    np.testing.assert_array_equal(first.vertices, here.vertices)
    np.testing.assert_array_equal(first.triangles, here.triangles)
    np.testing.assert_array_equal(first.colors, here.colors)
    np.testing.assert_array_equal(first.density, here.density)
    # The same child waits again and solves the next surface (no second start).
    assert ps._idle == [child] and child.poll() is None
    no_colors = np.empty((0, 3), np.uint8)
    second = ps.solve_poisson_apart(points[::2], normals[::2], no_colors, 4)
    assert ps._idle == [child]
    expected = ps.solve_poisson(points[::2], normals[::2], no_colors, 4)
    np.testing.assert_array_equal(second.vertices, expected.vertices)
    assert len(second.vertices) != len(first.vertices)  # a different surface, not the last one
    ps._close_idle()
    assert child.returncode == 0  # closing its stdin ends it


def test_a_dead_child_is_replaced_and_a_failed_solve_is_solved_here(no_children, caplog):
    points, normals, colors = _sphere()
    here = ps.solve_poisson(points, normals, colors, 5)
    ps.start_solver()
    (dead,) = ps._idle
    dead.kill()
    dead.wait()
    again = ps.solve_poisson_apart(points, normals, colors, 5)
    np.testing.assert_array_equal(again.vertices, here.vertices)
    assert dead not in ps._idle and len(ps._idle) == 1  # a new child, kept for the next
    # A child that fails the solve says so on stdout; the surface is then solved here.
    bad = np.full((10, 3), np.nan)
    # (Open3D's own error, here as in the child.)
    with (
        caplog.at_level("WARNING", logger="scanner.reconstruct.stages"),
        pytest.raises(Exception),  # noqa: B017
    ):
        ps.solve_poisson_apart(bad, bad, np.empty((0, 3), np.uint8), -1)
    assert "Poisson solver process failed (error: " in caplog.text


def test_a_wider_cube_is_solved_apart_as_here_and_two_children_start_at_once(no_children):
    points, normals, _ = _sphere()
    no_colors = np.empty((0, 3), np.uint8)
    ps.start_solver(2)
    assert len(ps._idle) == 2 and all(c.poll() is None for c in ps._idle)
    ps.start_solver(2)
    assert len(ps._idle) == 2  # ready ones are not started again
    wide = ps.solve_poisson_apart(points, normals, no_colors, 5, scale=2.0)
    expected = ps.solve_poisson(points, normals, no_colors, 5, 2.0)
    np.testing.assert_array_equal(wide.vertices, expected.vertices)
    np.testing.assert_array_equal(wide.triangles, expected.triangles)
    default = ps.solve_poisson(points, normals, no_colors, 5)
    assert len(default.vertices) != len(wide.vertices)  # the scale reached the solve


def test_a_solve_whose_parent_is_gone_leaves_no_folder_behind(no_children, tmp_path):
    """A parent killed during a solve never removes the request's folder: the child does."""
    points, normals, colors = _sphere()
    folder = tmp_path / "poisson-request"
    folder.mkdir()
    given, solved = folder / "in.npz", folder / "out.npz"
    np.savez(given, points=points, normals=normals, colors=colors, depth=5, scale=ps.DEFAULT_SCALE)
    child = ps._spawn()
    child.stdin.write(f"{given}\n{solved}\n")
    child.stdin.flush()
    child.stdout.close()  # nobody reads the answer ...
    child.stdin.close()  # ... and no request follows
    assert child.wait(timeout=120) == 0
    assert not folder.exists()

"""The fixture never enters the model: the model-side guard on synthetic clouds (flat, elongated,
hung off the centre vertical, a second hanging's rod). End to end: a simulated two-hanging scan
checked against the true rod lines (test_hangings.py); over the benchmark objects, a flat one
among them, scripts/bench_complete.py (`fixture_points_max`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruction.common.transforms import invert, make_pose, rotation_about, transform_points
from reconstruction.hangings.merge import in_own_frames
from reconstruction.surfaces.fixture import (
    fixture_points,
    points_on_fixture,
    without_fixture,
)
from tests.rods import CENTRE, ROD_RADIUS_M
from tests.rods import rod_line as _line

RNG = np.random.default_rng(4)


def _ellipsoid(semi_axes, n: int = 60_000, centre=CENTRE) -> np.ndarray:
    d = RNG.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return centre + d * np.asarray(semi_axes)


def _rod(x: float, y: float, z0: float, z1: float, n: int = 3000, noise_m=0.002) -> np.ndarray:
    """Points on a rod's surface (stereo noise across it) from z0 up to z1."""
    phi = RNG.uniform(0, 2 * math.pi, n)
    r = ROD_RADIUS_M + RNG.normal(0, noise_m, n)
    return np.column_stack([x + r * np.cos(phi), y + r * np.sin(phi), RNG.uniform(z0, z1, n)])


@pytest.mark.parametrize(
    "semi_axes, offset_m",
    [
        ((0.1, 0.05, 0.025), (0.0, 0.0)),  # flat: the most rod in view
        ((0.1, 0.025, 0.025), (0.0, 0.0)),  # elongated
        ((0.1, 0.05, 0.025), (0.03, -0.02)),  # hung off the centre vertical
    ],
)
def test_the_guard_cuts_the_rod_strip_and_none_of_the_object(semi_axes, offset_m):
    centre = CENTRE + [*offset_m, 0.0]
    body = _ellipsoid(semi_axes, centre=centre)
    # The rod hangs on the cell's line (the vertical above the scan centre) down to the surface.
    top = body[np.hypot(body[:, 0] - CENTRE[0], body[:, 1] - CENTRE[1]) < 0.002][:, 2].max()
    rod = _rod(CENTRE[0], CENTRE[1], top, CENTRE[2] + 0.2)
    cut = fixture_points(np.vstack([body, rod]), _line())
    assert not cut[: len(body)].any()
    # All of the rod above the object's surface around it (within 36 mm of the line; off the
    # centre vertical the surface still rises beside the clamp) but the first 12 mm.
    near = np.hypot(body[:, 0] - CENTRE[0], body[:, 1] - CENTRE[1]) < 0.036
    assert cut[len(body) :][rod[:, 2] > body[near, 2].max() + 0.012].all()
    assert cut[len(body) :].mean() > 0.8


def test_the_guard_leaves_an_object_without_a_rod_alone():
    body = _ellipsoid((0.1, 0.1, 0.1))
    assert without_fixture(body, [_line()]).all()


def test_each_hangings_rod_is_cut_on_its_own_line_in_the_merged_frame():
    body = _ellipsoid((0.1, 0.05, 0.025))
    rod0 = _rod(CENTRE[0], CENTRE[1], CENTRE[2] + 0.025, CENTRE[2] + 0.2)
    # The second hanging: turned about the centre by 120 deg; its rod arrives along the
    # turned line (T: second hanging's frame -> the first's).
    R = rotation_about(np.array([1.0, 1.0, 0.0]) / math.sqrt(2), math.radians(120))
    T = make_pose(R, CENTRE - R @ CENTRE)
    body1 = transform_points(invert(T), body)  # the same object as the second hanging holds it
    top1 = body1[np.hypot(body1[:, 0] - CENTRE[0], body1[:, 1] - CENTRE[1]) < 0.002][:, 2].max()
    rod1 = transform_points(T, _rod(CENTRE[0], CENTRE[1], top1, CENTRE[2] + 0.2))
    points = np.vstack([body, rod0, rod1])
    lines = [_line(), _line().moved(T)]
    keep = without_fixture(points, lines)
    assert keep[: len(body)].all()
    far0 = rod0[:, 2] > CENTRE[2] + 0.04
    assert not keep[len(body) : len(body) + len(rod0)][far0].any()
    # Above the turned object's surface around its line, all of that rod is cut.
    u1 = np.asarray(lines[1].u_W)
    along1, along_body = (rod1 - CENTRE) @ u1, (body - CENTRE) @ u1
    across_body = np.linalg.norm(body - CENTRE - np.outer(along_body, u1), axis=1)
    surface_top = along_body[across_body < 0.036].max()
    assert not keep[len(body) + len(rod0) :][along1 > surface_top + 0.012].any()


def test_the_cell_filter_sees_each_view_in_its_own_hangings_frame():
    T = make_pose(rotation_about(np.array([0.0, 0.0, 1.0]), 1.0), [0.1, 0.0, 0.0])
    seen = {}

    def remove(p_W, index):
        seen[index] = p_W
        return np.ones(len(p_W), bool)

    p_own = np.array([[0.4, 0.0, 1.2]])
    hook = in_own_frames(remove, [np.eye(4), T], {3: 0, 7: 1})
    hook(transform_points(T, p_own), 7)
    hook(p_own, 3)
    np.testing.assert_allclose(seen[7], p_own, atol=1e-12)
    np.testing.assert_allclose(seen[3], p_own, atol=1e-12)


def test_points_on_the_fixture_are_counted_above_the_object_only():
    body = _ellipsoid((0.1, 0.05, 0.025))
    rod = _rod(CENTRE[0], CENTRE[1], CENTRE[2] + 0.025, CENTRE[2] + 0.2, noise_m=0.0)
    assert points_on_fixture(body, body, _line()) == 0
    assert points_on_fixture(rod, body, _line()) == int((rod[:, 2] > CENTRE[2] + 0.035).sum())

"""Viewpoint generation and tour ordering, with stand-in reachability and costs."""

import math

import numpy as np
import pytest

from planners.ik import Viewpoint
from planners.tour import plan_tour, tour_cost
from reconstruction.common.errors import ScannerError
from reconstruction.common.sphere import fibonacci_directions
from scanner.configs.views import ViewpointConfig
from scanner.scan.viewpoints import generate_viewpoints
from scanner.scan_dir.views import PlannedView, ViewOption


def _min_angle(d):
    cos = np.clip(d @ d.T, -1, 1)
    np.fill_diagonal(cos, -1)
    return float(np.arccos(cos.max(axis=1)).min())


@pytest.mark.parametrize("n", [24, 48, 200])
def test_fibonacci_directions_are_even(n):
    d = fibonacci_directions(n)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # Tammes-like bound: n equal caps of angular radius a/2 cover at most the sphere, so the
    # best possible minimum angle is about sqrt(8 pi / (n sqrt 3)) (hexagonal packing).
    ideal = math.sqrt(8 * math.pi / (n * math.sqrt(3)))
    assert _min_angle(d) > 0.75 * ideal
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=0.03)  # no hemisphere favoured


def _cap_reachable(axis, half_angle):
    """Stand-in for the planner: a view is reachable inside a cap, with one config per roll."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)

    def reachable(vp: Viewpoint):
        d = np.subtract(vp.p_WM, vp.p_WT)
        d /= np.linalg.norm(d)
        if d @ axis < math.cos(half_angle):
            return []
        return [np.array([*d, vp.roll_rad, 0.0, 0.0])]

    return reachable


def test_reachable_distribution_spreads_views_over_the_reachable_cap():
    config = ViewpointConfig(count=12, candidates=600, roll_candidates=2)
    plan = generate_viewpoints(config, (0, 0, 1), _cap_reachable((-1, 0, -0.5), math.radians(35)))
    assert len(plan.views) == 12 and not plan.dropped
    dirs = np.array([v.direction for v in plan.views])
    axis = np.array([-1, 0, -0.5]) / np.linalg.norm([-1, 0, -0.5])
    assert np.all(dirs @ axis >= math.cos(math.radians(35)) - 1e-9)
    # 12 points in a 35 deg cap (area 2 pi (1 - cos 35)): hexagonal spacing ~ 18 deg.
    assert _min_angle(dirs) > math.radians(12)
    cap_fraction = (1 - math.cos(math.radians(35))) / 2
    assert plan.reachable_fraction == pytest.approx(cap_fraction, abs=0.02)
    for v in plan.views:
        assert v.viewpoint.distance_m == pytest.approx(0.5)
        assert len(v.options) == 2


def test_sphere_distribution_replaces_or_drops_unreachable_views():
    config = ViewpointConfig(
        count=24, distribution="sphere", replace_within_rad=math.radians(25), roll_candidates=1
    )
    plan = generate_viewpoints(config, (0, 0, 1), _cap_reachable((1, 0, 0), math.radians(40)))
    assert plan.dropped, "views far from the cap must be dropped and reported"
    assert all("unreachable" in d.reason for d in plan.dropped)
    assert len(plan.views) + len(plan.dropped) == 24
    dirs = np.array([v.direction for v in plan.views])
    assert np.all(dirs[:, 0] >= math.cos(math.radians(40)) - 1e-9)
    assert len({tuple(d.round(9)) for d in dirs}) == len(dirs)  # replacements never repeat


def test_no_reachable_view_is_a_user_error():
    with pytest.raises(ScannerError, match="no viewpoint at radius"):
        generate_viewpoints(ViewpointConfig(count=3), (0, 0, 1), lambda vp: [])


def test_bad_view_settings():
    with pytest.raises(ScannerError, match="at least 1 view"):
        ViewpointConfig(count=0)
    with pytest.raises(ScannerError, match="distribution"):
        ViewpointConfig(distribution="spiral")


def _views_on_circle(n, options=1):
    rng = np.random.default_rng(0)
    views = []
    for i in rng.permutation(n):
        a = 2 * math.pi * i / n
        opts = tuple(
            ViewOption(0.0, np.array([math.cos(a), math.sin(a)]) * (1 + k)) for k in range(options)
        )
        views.append(PlannedView(len(views), np.zeros(3), Viewpoint((0, 0, 0), (1, 0, 0)), opts))
    return views


def test_tour_beats_generation_order_and_finds_the_circle():
    views = _views_on_circle(20, options=2)

    def cost(a, b):
        return float(np.linalg.norm(a - b))

    start = np.array([1.0, 0.0])
    tour = plan_tour(start, views, cost)
    naive = tour_cost(start, views, range(len(views)), [0] * len(views), cost)
    assert sorted(tour.order) == list(range(20))
    assert tour.cost_s == pytest.approx(tour_cost(start, views, tour.order, tour.option, cost))
    # The optimum walks the inner circle once: 19 chords of 2 sin(pi/20).
    assert tour.cost_s <= 19 * 2 * math.sin(math.pi / 20) + 1e-6
    assert tour.cost_s < 0.5 * naive
    assert all(o == 0 for o in tour.option)  # the outer circle's options are never worth it

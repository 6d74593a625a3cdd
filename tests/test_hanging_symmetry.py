"""Hanging alignment of shapes with a symmetry: the texture picks the true turn among the
rotation grid's fits, and the turns no hypothesis reached are tried."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruction.common.transforms import (
    make_pose,
    rotation_about,
    rotation_angle_rad,
    transform_points,
)
from reconstruction.hangings.alignment import AlignmentConfig, alignment_error
from reconstruction.hangings.free_space import SeenSpace
from robots.models.objects import resolve_object
from robots.simulation.operator import hung_pose
from tests.partial_clouds import partial_cloud, stripes


def _fluted_vase_passes(seed: int):
    mesh = resolve_object("vase", 0.2)
    X0 = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    X1 = hung_pose(X0, seed, 1)
    ref, ref_colors = partial_cloud(mesh.vertices, mesh.triangles, X0, 0, stripes)
    moved, colors = partial_cloud(mesh.vertices, mesh.triangles, X1, 1, stripes)
    object_points = transform_points(X1, mesh.vertices)
    return (moved, colors), (ref, ref_colors), X0 @ np.linalg.inv(X1), object_points


def test_the_texture_ranks_the_rotation_grid_fits_of_a_fluted_vase(monkeypatch):
    """A fluted vase fits itself turned about its axis by a flute: the overlap alone keeps
    one such fit of the rotation grid by chance. The grid also keeps its best fits by texture:
    with the features left out and one fit kept per ranking, the true turn is found."""
    import reconstruction.hangings.alignment as pa

    (moved, colors), (ref, ref_colors), T_true, object_points = _fluted_vase_passes(0)
    monkeypatch.setattr(pa, "feature_hypotheses", lambda *a: [])
    config = AlignmentConfig(coarse_starts_kept=1)
    a = pa.align_pass(1, moved, ref, SeenSpace((), ()), config, colors, ref_colors)
    assert a.verified, a.failures
    moved_m, turned_rad = alignment_error(a.T, T_true, object_points)
    assert moved_m < 0.002 and math.degrees(turned_rad) < 1.0
    # Without the texture the same grid keeps its best fit by overlap alone: another turn.
    shape_only = pa.align_pass(1, moved, ref, SeenSpace((), ()), config)
    assert math.degrees(alignment_error(shape_only.T, T_true, object_points)[1]) > 5.0


def test_the_turns_no_hypothesis_reached_are_tried_and_the_texture_picks_the_true_one(
    monkeypatch,
):
    """Here no fit of the rotation grid lands on the true turn (they land one to four flutes
    away): the turns between the fits that fit the shape reveal its symmetry, and the others of
    that symmetry are tried. With texture the true one is found; without, the shape is refused
    as ambiguous rather than merged in a wrong turn."""
    import reconstruction.hangings.alignment as pa

    (moved, colors), (ref, ref_colors), T_true, object_points = _fluted_vase_passes(1)
    monkeypatch.setattr(pa, "feature_hypotheses", lambda *a: [])
    a = pa.align_pass(1, moved, ref, SeenSpace((), ()), AlignmentConfig(), colors, ref_colors)
    assert a.verified, a.failures
    moved_m, turned_rad = alignment_error(a.T, T_true, object_points)
    assert moved_m < 0.002 and math.degrees(turned_rad) < 1.0
    shape_only = pa.align_pass(1, moved, ref, SeenSpace((), ()), AlignmentConfig())
    assert not shape_only.verified
    assert any("ambiguous" in f for f in shape_only.failures)


def test_sibling_starts_complete_the_turns_of_a_symmetry():
    from reconstruction.hangings.symmetry import sibling_starts, turn_about_axis

    axis, point = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0]), [0.4, 0.1, 1.0]

    def turn(deg):
        R = rotation_about(axis, math.radians(deg))
        return make_pose(R, point - R @ point)

    T_true = make_pose(rotation_about(np.array([1.0, 0, 0]), 2.0), [0.05, 0.0, 0.02])
    # Two fits of an eight-fold shape, one and two flutes from the truth; a poor fit elsewhere.
    fits = [(0.5, turn(45) @ T_true), (0.48, turn(90) @ T_true), (0.1, turn(10) @ T_true)]
    starts = sibling_starts(fits, math.radians(10.0))
    assert len(starts) == 7
    errors = [alignment_error(S, T_true, [np.array(point)])[0] for S in starts]
    angles = sorted(math.degrees(rotation_angle_rad(S[:3, :3] @ T_true[:3, :3].T)) for S in starts)
    assert min(errors) < 1e-9 and angles[0] < 1e-6  # the truth is among them
    np.testing.assert_allclose(angles, [0, 45, 90, 90, 135, 135, 180], atol=1e-6)
    a, angle, p = turn_about_axis(turn(45))
    np.testing.assert_allclose(a, axis, atol=1e-12)
    assert math.degrees(angle) == pytest.approx(45.0)
    assert np.linalg.norm(np.cross(np.asarray(p) - point, axis)) < 1e-9  # on the axis
    # One good fit alone reveals no symmetry.
    assert sibling_starts(fits[:1] + fits[2:], math.radians(10.0)) == []

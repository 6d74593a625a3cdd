"""The same passes give the same alignment, to the bit: Open3D's ICP does not (it sums in no
fixed order), and the merged hangings' Poisson octree turns last-bit differences into another
mesh, so a second reconstruction of the same captures would not give the same model."""

from __future__ import annotations

import numpy as np

from reconstruction.common.transforms import make_pose, snapped
from reconstruction.hangings.alignment import AlignmentConfig
from reconstruction.hangings.free_space import SeenSpace
from robots.models.objects import resolve_object
from robots.simulation.operator import hung_pose
from tests.partial_clouds import partial_cloud, stripes


def test_aligning_the_same_passes_twice_gives_the_same_transform(monkeypatch):
    import reconstruction.hangings.alignment as pa

    mesh = resolve_object("vase", 0.2)
    X0 = make_pose(np.eye(3), [0.4, 0.0, 1.0])
    ref, ref_colors = partial_cloud(mesh.vertices, mesh.triangles, X0, 0, stripes)
    moved, colors = partial_cloud(mesh.vertices, mesh.triangles, hung_pose(X0, 0, 1), 1, stripes)
    monkeypatch.setattr(pa, "feature_hypotheses", lambda *a: [])  # the grid alone: quicker
    config = AlignmentConfig(coarse_starts_kept=1)
    runs = [
        pa.align_pass(1, moved, ref, SeenSpace((), ()), config, colors, ref_colors)
        for _ in range(2)
    ]
    assert all(r.verified for r in runs), [r.failures for r in runs]
    for r in runs[1:]:
        np.testing.assert_array_equal(r.T, runs[0].T)
    np.testing.assert_array_equal(snapped(runs[0].T, np.eye(4)), runs[0].T)

"""Next-best views: the candidate that sees the most unseen surface is chosen, and a scan with
extra views records and captures them."""

import numpy as np
import pytest

from reconstruction.evaluation.metrics import TriangleSurface, sample_surface, visible_mask
from reconstruction.surfaces.fused import FusedCloud
from scanner.scan.next_best_view import CoverageModel


def _sphere_seen_from(centres):
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.1, 80)
    truth = TriangleSurface(np.asarray(sphere.vertices), np.asarray(sphere.triangles))
    samples = sample_surface(truth, 60_000)
    seen = visible_mask(samples, truth, centres)
    return FusedCloud(
        samples.points[seen], np.zeros((seen.sum(), 3), np.uint8), samples.normals[seen]
    )


def test_the_next_view_looks_where_the_model_is_unseen():
    below = [np.array([0.4 * np.cos(a), 0.4 * np.sin(a), -0.3]) for a in np.linspace(0, 6, 8)]
    model = CoverageModel(_sphere_seen_from(below), below)
    before = model.coverage
    assert 0.3 < before < 0.95
    candidates = np.array([[0, 0, -1.0], [1.0, 0, 0], [0, 0, 1.0], [0, 0.6, 0.8]])
    candidates /= np.linalg.norm(candidates, axis=1, keepdims=True)
    choice = model.best([0, 0, 0], 0.5, candidates, taken=[])
    np.testing.assert_allclose(choice.direction, [0, 0, 1.0])  # straight above: all unseen
    assert choice.gain > 0.1
    model.add(0.5 * choice.direction)
    assert model.coverage == pytest.approx(before + choice.gain, abs=0.02)
    # A candidate within 10 deg of a view already taken is not offered again.
    again = model.best([0, 0, 0], 0.5, candidates, taken=[choice.direction])
    assert again is None or not np.allclose(again.direction, choice.direction)


@pytest.mark.slow
def test_a_scan_adds_the_next_best_views_it_was_allowed(tmp_path):
    import yaml

    from scanner.configs.scan import load_scan_config
    from scanner.scan.run import run_scan
    from scanner.scan_dir.captures import CaptureStore
    from tests.tiny_scan import TINY_SCAN

    path = tmp_path / "small.yaml"
    views = {**TINY_SCAN["views"], "count": 4, "max_extra_views": 2, "min_gain": 0.0}
    path.write_text(
        yaml.safe_dump(
            {**TINY_SCAN, "views": views, "object": "bracket", "hangings": 1, "reconstruct": False}
        )
    )
    result = run_scan(load_scan_config(path), tmp_path / "scan")
    manifest = CaptureStore.open(result.scan_dir).read_manifest()
    assert manifest["extra_views_done"] == [0]
    assert len(manifest["viewpoints"]) == 6 and len(manifest["hangings"][0]) == 6
    assert result.report["views_captured"] == 6
    assert result.report["stage_s"]["next_best_view"] > 0

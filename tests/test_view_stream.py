"""Per-view work streamed beside the capture loop gives exactly what the offline
reconstruction of the same captures gives."""

import numpy as np
import pytest
import yaml

from reconstruction.registration.filtering import filter_views
from reconstruction.stereo.rectification import compute_rectification
from scanner.reconstruct.scan_views import capture_views, geometry_filter, with_roi_centre
from scanner.reconstruct.stages import run_reconstruct
from scanner.reconstruct.view_stream import ViewStream, processing_hidden_s
from scanner.scan.decision import ViewOutcome
from scanner.scan_dir.manifest import open_scan


@pytest.fixture(scope="module")
def streamed_scan(tiny_scan):
    """The shared tiny scan: its views were streamed while the robot moved."""
    return tiny_scan


def test_the_scan_streamed_its_views_and_says_how_much_was_hidden(streamed_scan):
    r = streamed_scan.report
    assert r["views_captured"] == 5 and r["status"] == "complete"
    assert r["processing_s"] > 0
    assert 0 < r["processing_hidden_s"] <= r["processing_s"]


def test_streamed_views_equal_the_offline_ones(streamed_scan):
    scan = open_scan(streamed_scan.scan_dir)
    stream = ViewStream(scan)
    for index in scan.store.captured_indices():
        stream.submit(index)
    streamed = stream.finish()
    assert sorted(streamed.views) == scan.store.captured_indices() and not streamed.failed

    processing = scan.config.processing
    offline = capture_views(
        scan, compute_rectification(scan.camera_model), scan.X_FC_nominal, processing.stereo
    )
    config = with_roi_centre(processing.reconstruction, np.array(scan.config.scan_center_m))
    remove = geometry_filter(
        scan.config,
        scan.X_FC_nominal,
        scan.camera_model,
        offline.joints,
        processing.remove_margin_m,
    )
    views, clouds, _ = filter_views(offline.views, scan.X_FC_nominal, config.filter, remove)
    for view, cloud in zip(views, clouds):
        s = streamed.views[view.index]
        np.testing.assert_array_equal(s.view.points_C, view.points_C)
        np.testing.assert_array_equal(s.view.depth.depth_m, view.depth.depth_m)
        np.testing.assert_array_equal(s.cloud.points_C, cloud.points_C)
        np.testing.assert_array_equal(s.cloud.normals_C, cloud.normals_C)


def test_the_scans_model_equals_an_offline_reconstruction(streamed_scan, tmp_path):
    scan_dir = streamed_scan.scan_dir
    offline = run_reconstruct(scan_dir, results_dir=tmp_path / "offline")
    streamed = yaml.safe_load((scan_dir / "results" / "reconstruction.yaml").read_text())
    again = yaml.safe_load((tmp_path / "offline" / "reconstruction.yaml").read_text())
    # The tiny scan keeps its nominal mount (no hand-eye record); the X_FC used must agree.
    assert streamed.get("handeye") == again.get("handeye")
    assert streamed["X_FC"] == again["X_FC"]
    import open3d as o3d

    a = o3d.io.read_triangle_mesh(str(scan_dir / "results" / "mesh_poisson.ply"))
    b = o3d.io.read_triangle_mesh(str(tmp_path / "offline" / "mesh_poisson.ply"))
    np.testing.assert_array_equal(np.asarray(a.vertices), np.asarray(b.vertices))
    np.testing.assert_array_equal(np.asarray(a.triangles), np.asarray(b.triangles))
    assert offline.report["chamfer_mm"] == streamed_scan.report["chamfer_mm"]
    # Every pair was registered while the robot moved; offline, the same pairs, registered
    # in the same (capture) order, with the same results.
    _same_edges(streamed["edges"], again["edges"])
    assert streamed_scan.report["pairs_registered_while_scanning"] == len(streamed["edges"]) > 0
    assert offline.report["pairs_registered_while_scanning"] == 0


def _same_edges(a: list[dict], b: list[dict]) -> None:
    """The same pairs with the same decisions; their figures equal to Open3D's summation order
    (its ICP sums over threads in a varying order: ~1e-15 relative seen)."""
    assert [(e["source"], e["target"], e["kind"], e["status"]) for e in a] == [
        (e["source"], e["target"], e["kind"], e["status"]) for e in b
    ]
    for ea, eb in zip(a, b):
        for key, value in ea.items():
            if isinstance(value, float):
                np.testing.assert_allclose(value, eb[key], rtol=1e-9, atol=0, equal_nan=True)


def test_a_resumed_scan_streams_what_an_uninterrupted_one_would(streamed_scan, tmp_path):
    """Stopped after some captures and resumed: the resumed run streams the earlier captures
    first, in capture order, then the new ones as they come, so every pair is registered
    during the scan and the model is the one an offline reconstruction of the same captures
    gives (what an uninterrupted scan streams, by the test above)."""
    from scanner.scan.run import run_scan
    from tests.scan_copies import interrupted_copy

    out = interrupted_copy(streamed_scan.scan_dir, tmp_path / "scan", kept=2)
    before = open_scan(out).store.captured_indices()
    assert len(before) == 2

    resumed = run_scan(None, None, resume=out)
    report = resumed.report
    assert report["status"] == "complete" and report["views_captured"] == 5
    offline = run_reconstruct(out, results_dir=tmp_path / "offline")
    streamed = yaml.safe_load((out / "results" / "reconstruction.yaml").read_text())
    again = yaml.safe_load((tmp_path / "offline" / "reconstruction.yaml").read_text())
    _same_edges(streamed["edges"], again["edges"])
    assert report["pairs_registered_while_scanning"] == len(streamed["edges"]) > 0
    assert report["chamfer_mm"] == offline.report["chamfer_mm"]


def test_streamed_views_made_with_other_settings_are_not_used(streamed_scan, tmp_path):
    from dataclasses import replace

    from scanner.reconstruct.stages import _streamed_for

    scan = open_scan(streamed_scan.scan_dir)
    stream = ViewStream(scan)
    stream.submit(scan.store.captured_indices()[0])
    streamed = stream.finish()
    processing = scan.config.processing
    ready, filtered, arriving = _streamed_for(streamed, scan, processing, None, None)
    assert len(ready) == 1 and len(filtered) == 1
    assert arriving.arrived() == [(scan.store.captured_indices()[0], 0)]
    other = replace(processing, remove_margin_m=processing.remove_margin_m + 0.001)
    assert _streamed_for(streamed, scan, other, None, None) == ({}, {}, None)
    X_FC = scan.X_FC_nominal.copy()
    X_FC[0, 3] += 1e-3
    assert _streamed_for(streamed, scan, processing, X_FC, None) == ({}, {}, None)


def test_hidden_time_is_the_work_that_fits_in_the_next_motion():
    outcomes = [
        ViewOutcome(0, True, motion_s=2.0),
        ViewOutcome(1, True, motion_s=0.3),
        ViewOutcome(2, False, "unreachable"),
        ViewOutcome(3, True, motion_s=1.0),
    ]
    seconds = {0: 0.5, 1: 0.5, 3: 0.5}
    # View 0's work fits in the 0.3 s motion to view 1 only partly; view 1's next is a skip
    # (no motion); the last view has no motion after it.
    assert processing_hidden_s(outcomes, seconds) == pytest.approx(0.3)


def test_the_stream_samples_each_view_for_the_hand_eye_fit(streamed_scan):
    """With the hand-eye correction on, each streamed cloud is sampled for the fit as it is
    filtered: the fit after the last picture finds it made, and equal to its own sampling; and
    the Poisson solver processes start with the stream."""
    from dataclasses import replace

    from reconstruction.handeye.refine import _prepare, _prepared, _sampling, prepare_view

    scan = open_scan(streamed_scan.scan_dir)
    processing = scan.config.processing
    handeye = replace(processing.reconstruction.handeye, enabled=True)
    reconstruction = replace(processing.reconstruction, handeye=handeye)
    config = replace(scan.config, processing=replace(processing, reconstruction=reconstruction))
    from reconstruction.surfaces import poisson_solver

    poisson_solver._close_idle()
    stream = ViewStream(replace(scan, config=config))
    # The solver processes the reconstruction will use started with the stream: the model's
    # Poisson surface and the coverage estimate's closed surface.
    assert len(poisson_solver._idle) == 2
    for index in scan.store.captured_indices():
        stream.submit(index)
    streamed = stream.finish()
    fit = handeye.fine_fit
    for s in streamed.views.values():
        assert _sampling(fit) in _prepared[s.cloud]  # made by the stream
        made = prepare_view(s.cloud, fit)
        assert prepare_view(s.cloud, fit) is made
        fresh = _prepare(s.cloud, fit)
        np.testing.assert_array_equal(made.source_C, fresh.source_C)
        np.testing.assert_array_equal(made.normals_C, fresh.normals_C)

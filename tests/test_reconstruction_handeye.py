"""Hand-eye: AX = XB on exact motions, outlier rejection, and the joint X_FC refinement."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from synthetic_views import OBJECT_CENTER_W, ROBOT_SIDE, cap_directions, make_scan

from reconstruction.calibration.hand_eye import HAND_EYE_METHODS
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, twist_to_pose
from reconstruction.evaluation.metrics import handeye_error
from reconstruction.handeye.basin import CoarseHandEyeConfig, coarse_handeye
from reconstruction.handeye.correction import HandEyeConfig, correct_handeye, solve_axxb
from reconstruction.handeye.diagnosis import ConvergenceLimits, diagnose
from reconstruction.handeye.refine import RefineLevel, refine_on_clouds
from reconstruction.registration.filtering import FilterConfig, RegionOfInterest, filter_view
from reconstruction.registration.pairwise import IcpConfig, build_pyramid, select_pairs

X_FC_TRUE = make_pose(np.eye(3), [-0.06, 0.0, 0.08]) @ twist_to_pose(
    [0.01, -0.012, 0.006, 0.002, -0.0015, 0.001]
)


def _flange_poses(n: int, seed: int = 0) -> list[np.ndarray]:
    """Flange poses turning up to ~40 deg about varied axes (what a scan band gives)."""
    rng = np.random.default_rng(seed)
    return [
        make_pose(np.eye(3), [0.3, 0.0, 0.5])
        @ twist_to_pose(
            np.concatenate([0.4 * rng.standard_normal(3), 0.1 * rng.standard_normal(3)])
        )
        for _ in range(n)
    ]


@pytest.mark.parametrize("method", list(HAND_EYE_METHODS))
def test_axxb_recovers_X_FC_from_exact_motions(method):
    X_WF = _flange_poses(10)
    # The refined camera poses live in the pose graph's world, offset from W by any rigid
    # transform: AX = XB uses motions only, so the offset must not matter.
    X_offset = twist_to_pose([0.1, -0.2, 0.3, 0.01, 0.02, -0.03])
    X_WC = [X_offset @ X @ X_FC_TRUE for X in X_WF]
    s = solve_axxb(X_WF, X_WC, method, HandEyeConfig())
    if s.error:  # a solver may fail on a motion set; it must say so, not raise
        assert np.all(np.isnan(s.X_FC))
        return
    e = handeye_error(s.X_FC, X_FC_TRUE)
    # Exact data: every solver is exact up to its own numerics (Andreff's linear solution is
    # the loosest); 1 um and 1e-4 deg are far below anything a scan resolves.
    assert e["handeye_error_mm"] < 1e-3 and e["handeye_error_deg"] < 1e-4
    assert s.rms_translation_m < 1e-6 and s.rejected_views == ()


def test_axxb_rejects_an_outlier_view():
    X_WF = _flange_poses(12, seed=1)
    X_WC = [X @ X_FC_TRUE for X in X_WF]
    X_WC[5] = X_WC[5] @ twist_to_pose([0.0, math.radians(0.5), 0.0, 0.005, 0.0, 0.0])
    s = solve_axxb(X_WF, X_WC, "park", HandEyeConfig())
    assert 5 in s.rejected_views and len(s.rejected_views) <= 2
    e = handeye_error(s.X_FC, X_FC_TRUE)
    assert e["handeye_error_mm"] < 0.01 and e["handeye_error_deg"] < 0.001


# 10 views by a 480x360 camera (f 495 px: 1 mm pixels at 0.5 m, the filter's voxel): the fits
# below cost as many views and points, and every figure they are checked against holds there
# (measured: the joint refinement 0.27 mm here, 0.22 mm from 16 views at 640x480; the coarse
# stage then the fine fit 0.24 mm here, 0.27 mm there).
SCAN_SIZE = {
    "directions": cap_directions(10, ROBOT_SIDE, math.radians(35.0)),
    "image_size": (480, 360),
    "focal_px": 495.0,
}


@pytest.fixture(scope="module")
def bracket_scan():
    """10 views of the bracket over the RX60's band (35 deg cap), 0.3 mm depth noise, per-view
    flange errors of 0.05 mm / 0.005 deg (joint offsets), nominal X_FC 3 mm / 1 deg off."""
    scan = make_scan("bracket", **SCAN_SIZE)
    roi = RegionOfInterest(center_m=tuple(OBJECT_CENTER_W))
    X_WC_kin = [v.X_WF @ scan.X_FC_nominal for v in scan.views]
    clouds = [
        filter_view(v.index, v.points_C, v.colors, X, FilterConfig(roi=roi))
        for v, X in zip(scan.views, X_WC_kin)
    ]
    pyramids = [build_pyramid(c, IcpConfig()) for c in clouds]
    pairs = [(p.source, p.target) for p in select_pairs(X_WC_kin, pyramids, IcpConfig())]
    return scan, clouds, pairs


def test_joint_refinement_recovers_the_mount_error(bracket_scan):
    scan, clouds, pairs = bracket_scan
    X_WF = [v.X_WF for v in scan.views]
    before = handeye_error(scan.X_FC_nominal, scan.X_FC_true)
    assert before["handeye_error_mm"] == pytest.approx(3.0)
    r = refine_on_clouds(clouds, X_WF, pairs, scan.X_FC_nominal, HandEyeConfig().fine_fit)
    after = handeye_error(r.X_FC, scan.X_FC_true)
    # The target: 0.5 mm and 0.1 deg. What limits it here is the per-view flange error
    # (0.05 mm), not the depth noise (without flange errors it reaches ~0.02 mm).
    assert after["handeye_error_mm"] < 0.5
    assert after["handeye_error_deg"] < 0.1
    assert r.converged and r.rms_after_m < r.rms_before_m
    assert r.rms_after_m < 0.0005  # ~ the depth noise of two views, not the 3 mm / 1 deg blur


def test_wide_gates_on_a_share_of_the_points_end_where_all_points_do(bracket_scan):
    """The default's first two gates match a quarter of each view's points; the last gate
    matches them all and decides: the same mount as with every point at every gate (within
    a few micrometres, far below the 0.5 mm target), from a 3 mm / 1 deg start."""
    from types import SimpleNamespace

    from reconstruction.handeye.refine import _level_sources

    scan, clouds, pairs = bracket_scan
    X_WF = [v.X_WF for v in scan.views]
    fit = HandEyeConfig().fine_fit
    assert [level.points_per_view for level in fit.levels] == [250, 250, 0]
    every = replace(fit, levels=tuple(replace(lv, points_per_view=0) for lv in fit.levels))
    shared = refine_on_clouds(clouds, X_WF, pairs, scan.X_FC_nominal, fit)
    full = refine_on_clouds(clouds, X_WF, pairs, scan.X_FC_nominal, every)
    apart = handeye_error(shared.X_FC, full.X_FC)
    assert apart["handeye_error_mm"] < 0.005 and apart["handeye_error_deg"] < 0.001
    assert shared.converged and shared.n_matches == full.n_matches  # the last gate: all points
    truth = handeye_error(shared.X_FC, scan.X_FC_true)
    assert truth["handeye_error_mm"] < 0.5 and truth["handeye_error_deg"] < 0.1
    # Every k-th point: at most the level's share, spread over the whole view.
    view = SimpleNamespace(source_C=np.arange(3003.0)[:, None] * np.ones(3))
    (thinned,) = _level_sources([view], 250)
    assert len(thinned) <= 250 and thinned[0, 0] == 0 and thinned[-1, 0] > 2900
    assert _level_sources([view], 0)[0] is view.source_C
    assert len(_level_sources([view], 5000)[0]) == 3003


def test_a_view_is_sampled_once_and_alike_whichever_views_come_before_it(bracket_scan):
    """The fit's sampling of a view is made once per cloud and sampling (the scan's view
    stream makes it as the view arrives) and depends on that view alone: the same sources
    whether it is prepared first or after others, for the same fit."""
    from reconstruction.handeye.refine import prepare_view

    scan, clouds, pairs = bracket_scan
    fit = HandEyeConfig().fine_fit
    copies = [replace(c) for c in clouds]  # new objects: nothing prepared for them yet
    first = prepare_view(copies[5], fit)
    assert prepare_view(copies[5], fit) is first
    assert len(first.source_C) == fit.max_points_per_view < len(copies[5])
    other = replace(fit, voxel_size_m=2 * fit.voxel_size_m)
    assert prepare_view(copies[5], other) is not first
    again = [replace(c) for c in clouds]
    later = [prepare_view(c, fit) for c in again][5]  # views 0-4 sampled before it
    np.testing.assert_array_equal(later.source_C, first.source_C)
    np.testing.assert_array_equal(later.target_C, first.target_C)
    X_WF = [v.X_WF for v in scan.views]
    # A fit on views prepared in advance is the fit that prepares them itself.
    ahead = refine_on_clouds(again, X_WF, pairs, scan.X_FC_nominal, fit)
    itself = refine_on_clouds([replace(c) for c in clouds], X_WF, pairs, scan.X_FC_nominal, fit)
    np.testing.assert_array_equal(ahead.X_FC, itself.X_FC)


def test_the_stated_sigma_holds_the_true_error_and_converged_claims_it(bracket_scan):
    """The fit states its accuracy from the views (delete-one-view jackknife): the true error
    lies within 3 sigma, where the formal sigma (every match independent) is far too small to
    hold the per-view flange errors; a fit that cannot state a sigma within the limits, or is
    still moving by half of it, is not converged."""
    scan, clouds, pairs = bracket_scan
    X_WF = [v.X_WF for v in scan.views]
    r = refine_on_clouds(clouds, X_WF, pairs, scan.X_FC_nominal, HandEyeConfig().fine_fit)
    error = handeye_error(r.X_FC, scan.X_FC_true)
    sigma_mm, sigma_deg = 1e3 * r.sigma_translation_m, math.degrees(r.sigma_rotation_rad)
    assert error["handeye_error_mm"] <= 3 * sigma_mm, (error, sigma_mm)
    assert error["handeye_error_deg"] <= 3 * sigma_deg, (error, sigma_deg)
    # Measured: 0.23 mm / 0.017 deg stated for a true 0.27 mm / 0.015 deg; the formal
    # translation sigma is 0.03 mm, 9x below the true error.
    formal_mm = 1e3 * float(np.linalg.norm(r.formal_std[3:]))
    assert formal_mm < error["handeye_error_mm"] / 3 < sigma_mm
    assert sigma_mm < 0.5 and sigma_deg < 0.1  # informative: within the targets
    limits = ConvergenceLimits()
    assert diagnose(r.X_FC, r, None, None, limits).converged
    unknown = replace(r, sigma_translation_m=math.nan)
    assert "cannot state its accuracy" in diagnose(r.X_FC, unknown, None, None, limits).failures[0]
    loose = replace(r, sigma_rotation_rad=math.radians(0.5))
    assert "pin X_FC down" in diagnose(r.X_FC, loose, None, None, limits).failures[0]
    moving = replace(r, last_step_m=r.sigma_translation_m)
    assert "still moving" in diagnose(r.X_FC, moving, None, None, limits).failures[0]


def test_correction_reports_every_solver_and_respects_the_sanity_limits(bracket_scan):
    scan, clouds, pairs = bracket_scan
    X_WF = [v.X_WF for v in scan.views]
    X_WC_true = scan.X_WC_true
    cfg = HandEyeConfig(refine=False)
    result = correct_handeye(clouds, X_WF, X_WC_true, pairs, scan.X_FC_nominal, cfg)
    assert set(result.axxb) == set(HAND_EYE_METHODS)
    assert result.source == "axxb:park"
    # With tight limits nothing is trusted: the nominal X_FC stays, and the notes say why.
    tight = HandEyeConfig(refine=False, max_correction_m=0.001)
    result = correct_handeye(clouds, X_WF, X_WC_true, pairs, scan.X_FC_nominal, tight)
    assert result.source == "nominal" and result.notes
    np.testing.assert_array_equal(result.X_FC, scan.X_FC_nominal)


def test_bad_settings_are_user_errors():
    with pytest.raises(ScannerError, match="valid|one of"):
        HandEyeConfig(axxb_method="magic")
    with pytest.raises(ScannerError):
        HandEyeConfig(refine_levels=())


@pytest.fixture(scope="module")
def rough_mount_scan():
    """The bracket scan with the camera mounted 40 mm / 10 deg off its nominal pose (a
    hand-made mount), clouds cleaned at the nominal poses as a scan would."""
    scan = make_scan(
        "bracket", **SCAN_SIZE, handeye_error_m=0.04, handeye_error_rad=math.radians(10.0)
    )
    roi = RegionOfInterest(center_m=tuple(OBJECT_CENTER_W))
    clouds = [
        filter_view(
            v.index, v.points_C, v.colors, v.X_WF @ scan.X_FC_nominal, FilterConfig(roi=roi)
        )
        for v in scan.views
    ]
    return scan, clouds


def test_coarse_stage_finds_a_rough_mount_and_the_fine_fit_finishes_it(rough_mount_scan):
    scan, clouds = rough_mount_scan
    X_WF = [v.X_WF for v in scan.views]
    before = handeye_error(scan.X_FC_nominal, scan.X_FC_true)
    assert before["handeye_error_mm"] == pytest.approx(40.0)
    everything = [list(range(len(clouds)))]
    coarse = coarse_handeye(clouds, X_WF, everything, scan.X_FC_nominal, CoarseHandEyeConfig())
    mid = handeye_error(coarse.X_FC, scan.X_FC_true)
    assert mid["handeye_error_mm"] < 2.0 and mid["handeye_error_deg"] < 0.3
    pairs = [(i, j) for i in range(len(clouds)) for j in range(i + 1, len(clouds))]
    fine = refine_on_clouds(clouds, X_WF, pairs, coarse.X_FC, HandEyeConfig().fine_fit)
    after = handeye_error(fine.X_FC, scan.X_FC_true)
    assert after["handeye_error_mm"] < 0.5 and after["handeye_error_deg"] < 0.1
    verdict = diagnose(fine.X_FC, fine, None, coarse.X_FC, ConvergenceLimits())
    assert verdict.converged, verdict.failures


def test_a_restart_that_loses_all_overlap_is_skipped_not_fatal(rough_mount_scan, monkeypatch):
    # From a turned start the fit can carry the views apart until no match is left (seen on a
    # 3-view scan); the coarse stage then keeps its other fits instead of failing the scan.
    import reconstruction.handeye.basin as basin

    scan, clouds = rough_mount_scan
    X_WF = [v.X_WF for v in scan.views]
    everything = [list(range(len(clouds)))]
    calls = []
    real_fit = basin.refine_on_clouds

    def fit_losing_overlap_on_restarts(clouds, X_WF, pairs, start, settings):
        calls.append(start)
        if len(calls) > 1:
            raise ScannerError("hand-eye refinement: the views do not overlap")
        fit = real_fit(clouds, X_WF, pairs, start, settings)
        return replace(fit, match_fraction=0.0)  # poor: every restart is tried

    monkeypatch.setattr(basin, "refine_on_clouds", fit_losing_overlap_on_restarts)
    coarse = coarse_handeye(clouds, X_WF, everything, scan.X_FC_nominal, CoarseHandEyeConfig())
    assert len(calls) == 7  # the nominal start and six turned ones
    assert coarse is not None and coarse.match_fraction == 0.0


def test_a_fit_stuck_far_from_the_truth_is_diagnosed(rough_mount_scan):
    """A fit with only narrow gates from 40 mm / 10 deg ends in a wrong X_FC; the diagnosis
    must say so without the truth."""
    scan, clouds = rough_mount_scan
    X_WF = [v.X_WF for v in scan.views]
    pairs = [(i, j) for i in range(len(clouds)) for j in range(i + 1, len(clouds))]
    narrow = replace(HandEyeConfig().fine_fit, levels=(RefineLevel(0.005, 10),))
    stuck = refine_on_clouds(clouds, X_WF, pairs, scan.X_FC_nominal, narrow)
    error = handeye_error(stuck.X_FC, scan.X_FC_true)
    assert error["handeye_error_mm"] > 2.0  # the premise: it did not find the mount
    verdict = diagnose(stuck.X_FC, stuck, None, None, ConvergenceLimits())
    assert not verdict.converged
    assert any("points meet" in f or "match RMS" in f for f in verdict.failures)


def test_diagnosis_flags_disagreeing_solvers(rough_mount_scan):
    scan, clouds = rough_mount_scan
    X_WF = [v.X_WF for v in scan.views]
    pairs = [(i, j) for i in range(len(clouds)) for j in range(i + 1, len(clouds))]
    good = refine_on_clouds(clouds, X_WF, pairs, scan.X_FC_true, HandEyeConfig().fine_fit)
    assert diagnose(good.X_FC, good, scan.X_FC_true, good.X_FC, ConvergenceLimits()).converged
    off = scan.X_FC_true @ twist_to_pose([0.0, 0.0, math.radians(1.0), 0.005, 0.0, 0.0])
    verdict = diagnose(good.X_FC, good, off, off, ConvergenceLimits())
    assert [f.split(" ")[0] for f in verdict.failures] == ["AX", "the", "the"]
    # Two answers 5 mm apart: the stated sigma is at least half of that, beyond the limits.
    assert "pin X_FC down" in verdict.failures[2]
    assert verdict.sigma_translation_m >= 0.0025

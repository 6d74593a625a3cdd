"""Eye-in-hand and eye-to-hand calibration in the simulator, against the simulator's truth.

The accuracy checks read the shared 8-station run at the product's full resolution (1280x960,
tests/calibration_runs.py): at 640x480 the focal length came out 0.5-0.8 % off (corner precision
halves, the board covers fewer pixels) and the hand-eye translation 2-3.3 mm, so a reduced
resolution would not test the product's accuracy. The default 20 stations and the default
eye-to-hand set-up are scripts/bench_calibration.py's. How a run is driven (a hardware driver,
resume) is checked on the small half-resolution run: the same result whichever way the same
stations were visited.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from report_units import keys_breaking_the_unit_rule

from reconstruction.calibration.eye_in_hand import calibrate_hand_eye
from reconstruction.calibration.file import load_calibration
from reconstruction.calibration.hand_eye import motion_summary
from reconstruction.calibration.observations import PoseObservation
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, pose_difference
from robots.models import camera_tool
from robots.simulation.truth import load_truth
from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.eye_in_hand import run_eye_in_hand
from scanner.calibrate.eye_to_hand import run_eye_to_hand
from scanner.scan_dir.captures import CaptureStore
from tests.calibration_runs import EIGHT_STATIONS, SMALL, eight_stations, small, solved_again

HANDEYE_TOL_M = 0.3e-3  # the target
HANDEYE_TOL_RAD = math.radians(0.05)
STEREO_RMS_TOL_PX = 0.3
EYE_TO_HAND_MEAN_TOL_M = 1.0e-3
STATIONS = EIGHT_STATIONS.stations.count


@pytest.fixture(scope="module")
def sim_calibration(run_dir):
    return eight_stations(run_dir)


def test_hand_eye_matches_the_truth(sim_calibration):
    report = sim_calibration.report
    truth, extra = load_truth(sim_calibration.out_dir / "truth.yaml")
    dt, dr = pose_difference(sim_calibration.solution.hand_eye.X_FC, truth.X_FC)
    assert dt < HANDEYE_TOL_M and dr < HANDEYE_TOL_RAD
    assert report["truth"]["handeye_error_mm"] == pytest.approx(1e3 * dt)  # reports: mm
    # The nominal X_FC is 3 mm and 1 deg off (the error model): calibration removed that.
    nominal_dt, nominal_dr = pose_difference(camera_tool.nominal_X_FC(), truth.X_FC)
    assert nominal_dt == pytest.approx(3e-3, rel=0.01)
    assert nominal_dr == pytest.approx(math.radians(1.0), rel=0.01)
    X_WB = sim_calibration.solution.hand_eye.X_WB
    assert pose_difference(X_WB, np.array(extra["X_WB"]))[0] < 1e-3


def test_calibration_reports_follow_the_unit_rule(sim_calibration):
    assert keys_breaking_the_unit_rule(sim_calibration.report) == []
    text = (sim_calibration.out_dir / "results" / "report.txt").read_text()
    assert "printed in mm and degrees" in text and "against the simulator's truth" in text


def test_stereo_calibration(sim_calibration):
    report = sim_calibration.report
    assert report["stereo_rms_px"] <= STEREO_RMS_TOL_PX
    truth = report["truth"]
    assert max(truth["focal_error_px"]) < 1.0  # of 1320 px
    assert truth["baseline_error_mm"] < 0.1
    assert report["poses_used"] == report["poses"] == STATIONS
    assert report["poses_outliers"] == [] and report["poses_board_not_found"] == []


def test_stations_are_well_conditioned(sim_calibration):
    solution = sim_calibration.solution
    summary = motion_summary([o.X_WF for o in solution.observations], math.radians(2))
    assert summary.max_rotation_rad > math.radians(60)
    assert summary.axis_spread_rad > math.radians(60)


def test_files_written(sim_calibration):
    out = sim_calibration.out_dir
    store = CaptureStore.open(out)
    assert store.read_manifest()["kind"] == "calibration"
    assert len(store.captured_indices()) == STATIONS
    calibration = load_calibration(sim_calibration.calibration_file)
    assert np.allclose(calibration.X_FC, sim_calibration.solution.hand_eye.X_FC)
    assert calibration.stereo is not None and calibration.stereo.baseline_m == pytest.approx(
        0.12, abs=1e-3
    )
    text = (out / "results" / "report.txt").read_text()
    assert "against the simulator's truth" in text and "OpenCV park" in text


def test_offline_recalibration_of_a_run_keeps_the_earlier_result(sim_calibration, run_dir):
    # The run's folder (a copy) calibrated again (with --robot-offsets: the re-solve
    # test_calibration_outputs.py reads too) while it holds the run's own results.
    run = solved_again(run_dir)
    root = run.out_dir
    first = (sim_calibration.results_dir / "calibration.yaml").read_bytes()
    assert run.results_dir == root / "results-2"
    assert (root / "results" / "calibration.yaml").read_bytes() == first
    truth, _ = load_truth(root / "truth.yaml")
    dt, dr = pose_difference(load_calibration(run.calibration_file).X_FC, truth.X_FC)
    assert dt < HANDEYE_TOL_M and dr < HANDEYE_TOL_RAD


def test_an_injected_bad_pose_is_rejected(sim_calibration):
    solution = sim_calibration.solution
    observations = list(solution.observations)
    bad = observations[7]
    # The robot reports a pose 4 mm and 0.5 deg off where it stood (a dropped encoder count,
    # a pose file line from another run...).
    c, s = math.cos(math.radians(0.5)), math.sin(math.radians(0.5))
    X_err = make_pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), [0.004, 0, 0])
    observations[7] = PoseObservation(bad.name, bad.X_WF @ X_err, bad.left, bad.right)
    result = calibrate_hand_eye(CalibrateConfig().board, observations, solution.calibration.stereo)
    assert result.outliers == [bad.name]
    truth, _ = load_truth(sim_calibration.out_dir / "truth.yaml")
    dt, dr = pose_difference(result.X_FC, truth.X_FC)
    assert dt < HANDEYE_TOL_M and dr < HANDEYE_TOL_RAD


@pytest.mark.slow
def test_eye_to_hand_held_out_error(tmp_path):
    # The grid's 8 corners (one out of the arm's reach), 10 held-out points, 4 frames each;
    # the default 27 grid points, 100 held-out and 20 frames are bench_calibration's.
    config = CalibrateConfig()
    e2h = replace(config.eye_to_hand, grid_spacing_m=0.2, held_out=10, frames=4)
    report = run_eye_to_hand(replace(config, eye_to_hand=e2h), tmp_path)
    held_out = report["held_out"]
    assert held_out["count"] == 10
    assert held_out["mean_distance_mm"] <= 1e3 * EYE_TO_HAND_MEAN_TOL_M  # measured: 0.52 mm
    assert report["grid_points"] == 8 and report["fit_points_used"] >= 7
    assert (tmp_path / "results" / "eye_to_hand.yaml").is_file()


def test_an_unreachable_board_is_a_clear_error():
    from robots.models.calibration_board import BoardPlacement
    from scanner.calibrate.eye_in_hand import build_world, planner_reachable
    from scanner.calibrate.stations import plan_stations

    config = replace(CalibrateConfig(), placement=BoardPlacement(center_m=(1.5, 0.0, 0.2)))
    world = build_world(config)
    with pytest.raises(ScannerError, match=r"only 0 of \d+ candidate stations .* move the board"):
        plan_stations(
            config.stations,
            config.board,
            world.X_WB,
            world.stereo,
            world.X_FC,
            planner_reachable(world),
            world.sim.robot.joint_positions(),
        )


def test_eye_in_hand_on_a_hardware_driver(tmp_path, run_dir):
    hardware = replace(SMALL, driver="tests.simulated_hardware:connect_board_cell")
    run = run_eye_in_hand(hardware, tmp_path / "hw")
    assert not (tmp_path / "hw" / "truth.yaml").exists()
    assert run.report.get("truth") is None
    # The driver wraps the same seeded simulator (its truth is known to the test only): the
    # same stations, the same images, the same X_FC as the simulated run. How close that is
    # to the truth is the simulated run's accuracy (bench_calibration.py; 8 stations above).
    simulated = small(run_dir)
    assert _stations(run.out_dir) == _stations(simulated.out_dir)
    dt, dr = pose_difference(run.solution.hand_eye.X_FC, simulated.solution.hand_eye.X_FC)
    assert dt < 1e-6 and dr < 1e-6  # measured: 2e-10 m, 4e-10 rad
    assert run.report["poses_used"] == SMALL.stations.count


def _stations(out_dir) -> list[list[float]]:
    """The joints of a run's planned stations, in order."""
    return [s["q_rad"] for s in CaptureStore.open(out_dir).read_manifest()["stations"]]


def test_an_interrupted_calibration_resumes_without_repeating_captures(tmp_path, run_dir):
    config = SMALL
    out = tmp_path / "cal"

    def stop_after_three(done, total):
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_eye_in_hand(config, out, progress=stop_after_three)
    store = CaptureStore.open(out)
    assert store.captured_indices() == [0, 1, 2]
    before = {i: (out / "captures" / f"{i:04d}" / "left.png").read_bytes() for i in range(3)}
    with pytest.raises(ScannerError, match="exists and is not empty.*--resume"):
        run_eye_in_hand(config, out)
    other_board = replace(config, board=replace(config.board, spacing_m=0.025))
    with pytest.raises(ScannerError, match="different board"):
        run_eye_in_hand(other_board, out, resume=True)

    run = run_eye_in_hand(config, out, resume=True)
    count = config.stations.count
    assert CaptureStore.open(out).captured_indices() == list(range(count))
    for i, data in before.items():
        assert (out / "captures" / f"{i:04d}" / "left.png").read_bytes() == data
    assert run.report["poses"] == count
    # The same stations as the run that was not interrupted, the same X_FC but for the image
    # noise of the captures after the resume (drawn anew: measured 0.03 mm / 0.022 deg apart).
    # How close that is to the truth is the simulated run's accuracy (bench_calibration.py).
    whole = small(run_dir)
    assert _stations(out) == _stations(whole.out_dir)
    dt, dr = pose_difference(run.solution.hand_eye.X_FC, whole.solution.hand_eye.X_FC)
    assert dt < 0.3e-3 and dr < math.radians(0.1)
    assert run.report["truth"]["handeye_error_mm"] > 0


def test_resume_of_a_folder_that_is_not_a_calibration(tmp_path):
    from scanner.scan_dir.captures import CaptureStore as Store

    Store.create(tmp_path / "scan", {"kind": "scan", "pose_count": 1})
    with pytest.raises(ScannerError, match="not a calibration directory"):
        run_eye_in_hand(CalibrateConfig(), tmp_path / "scan", resume=True)

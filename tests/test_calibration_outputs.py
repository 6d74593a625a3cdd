"""What a calibration shows its user: corner pictures worst first, X_FC's sigma in the file and
the report, and a report that judges each figure (the shared simulated eye-in-hand run, 8
stations: tests/calibration_runs.py)."""

import re

import cv2
import numpy as np
import pytest

from reconstruction.calibration.file import load_calibration
from scanner.calibrate.corners import DETECTED_BGR, REPROJECTED_BGR
from scanner.calibrate.judge import BANDS
from tests.calibration_runs import eight_stations, solved_again

NAME = re.compile(r"(\d+)_(worst_)?(\w+)_(left|right)_rms(\d+\.\d+)px\.png")


@pytest.fixture(scope="module")
def run(run_dir):
    return eight_stations(run_dir)


def _pictures(run):
    return sorted((run.results_dir / "corners").iterdir())


def test_one_corner_picture_per_image_worst_first(run):
    names = [p.name for p in _pictures(run)]
    assert names == run.report["corner_pictures"]
    assert len(names) == 2 * run.report["poses_used"] == 16  # left and right of every pose
    parsed = [NAME.fullmatch(n) for n in names]
    assert all(parsed)
    assert parsed[0].group(2) == "worst_" and not any(m.group(2) for m in parsed[1:])
    rms = [float(m.group(5)) for m in parsed]
    assert rms == sorted(rms, reverse=True)
    # Left and right pictures of a pose together give the pose's RMS in the report.
    by_pose = {}
    for m in parsed:
        by_pose.setdefault(m.group(3), []).append(float(m.group(5)))
    per_pose = {p["name"]: p["rms_px"] for p in run.report["per_pose"]}
    for name, (a, b) in by_pose.items():
        # Same corner count in both images (the whole board is in view): RMS of the two.
        assert np.sqrt((a * a + b * b) / 2) == pytest.approx(per_pose[name], abs=0.01)
    assert "corner pictures: 16 in corners/" in (run.results_dir / "report.txt").read_text()


def test_a_picture_marks_detected_and_reprojected_corners(run):
    solution = run.solution
    path = _pictures(run)[0]
    m = NAME.fullmatch(path.name)
    image = cv2.imread(str(path))
    assert image.shape[1] <= 1280
    obs = next(o for o in solution.observations if o.name == m.group(3))
    detected = getattr(obs, m.group(4)).pixels
    # A ring of DETECTED colour around each detected corner, a REPROJECTED cross at its centre
    # (the corners lie within a fraction of a pixel of the reprojection).
    green = np.all(np.abs(image.astype(int) - DETECTED_BGR) < 60, axis=2)
    red = np.all(np.abs(image.astype(int) - REPROJECTED_BGR) < 60, axis=2)
    for u, v in detected[::7]:
        u, v = round(u), round(v)
        assert green[v - 8 : v + 9, u - 8 : u + 9].any()
        assert red[v - 2 : v + 3, u - 2 : u + 3].any()
    assert not red[200:, :].all()  # not a flood of colour
    assert red.sum() < 0.02 * red.size and green.sum() < 0.02 * green.size


def test_x_fc_sigma_in_the_file_and_the_report(run):
    quality = load_calibration(run.calibration_file).quality
    sigma = quality["X_FC_sigma"]
    assert sigma["frame"] == "C"
    t, r = np.array(sigma["translation_m"]), np.array(sigma["rotation_rad"])
    assert np.all((t > 1e-6) & (t < 1e-3)) and np.all((r > 1e-6) & (r < np.radians(0.2)))
    assert run.report["X_FC_sigma"] == sigma
    # The truth's error lies within 3 sigma on every axis of this run.
    assert max(run.report["truth"]["X_FC_sigma_ratios"]) < 3
    text = (run.results_dir / "report.txt").read_text()
    mm = re.search(r"translation \(([\d.]+), ([\d.]+), ([\d.]+)\) mm", text)
    assert [float(v) for v in mm.groups()] == pytest.approx(1e3 * t, abs=1e-3)


def test_the_report_judges_every_figure_and_names_the_options(run):
    text = (run.results_dir / "report.txt").read_text()
    for key, band in BANDS.items():
        if run.report.get(key) is None:
            continue
        line = next(line for line in text.splitlines() if line.strip().startswith(band.label))
        assert band.band() in line
        assert f"[{band.verdict(run.report[key])}]" in line
    assert run.report["epipolar_median_px"] < 0.2  # the true cameras' pair rectifies well
    assert re.search(r"^verdict: (good|fair|poor)", text, re.M)
    options = next(line for line in text.splitlines() if line.startswith("options:"))
    assert "--board chessboard 10x7" in options and "--stations 8" in options


def test_the_recorded_run_solved_again_with_the_robots_own_errors(run, run_dir):
    """`--robot-offsets` on the rendered run's captures: the encoder offsets of the joints the
    eight stations make observable come out within 0.005 deg of the simulator's (measured:
    0.0021 deg at worst), the others are named with the reason, held-out prediction improves
    (0.46 -> 0.08 px) and X_FC comes closer to the true mount (0.116 -> 0.086 mm); the file
    carries the correction for scans."""
    again = solved_again(run_dir)
    robot = again.report["robot_errors"]
    assert robot["kept"] and robot["held_out_px_with"] < robot["held_out_px_without"]
    assert {"joint 2 zero", "joint 3 zero", "joint 4 zero", "joint 5 zero"} <= set(
        robot["estimated"]
    )
    assert "about the base axis" in robot["not_observable"]["joint 1 zero"]
    errors = again.report["truth"]["joint_offset_errors_deg"]
    assert set(errors) == {"joint 2", "joint 3", "joint 4", "joint 5"}
    assert max(abs(v) for v in errors.values()) < 0.005, errors
    assert again.report["truth"]["handeye_error_mm"] < run.report["truth"]["handeye_error_mm"]
    correction = load_calibration(again.calibration_file).robot
    assert np.allclose(correction.joint_offsets_rad, robot["joint_offsets_rad"])
    assert robot["note"] in (again.results_dir / "report.txt").read_text()

"""Camera-only calibration (`scanner calibrate --offline DIR` without robot poses) on OpenCV's
real stereo sample (10x7 squares), and its bad input.

The calibration runs on the sample's first 5 of 13 pairs: OpenCV's stereoCalibrate takes 1.5 s
on them, 11 s on all 13, and the figures below hold on both (measured on 5 pairs: stereo RMS
0.203 px, epipolar median / p95 0.079 / 0.284 px, focal 534.7 / 537.5 px, baseline 83.2 mm).
The whole sample's figures are scripts/bench_real.py's (`--parts opencv_sample`)."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from reconstruction.calibration.file import load_calibration
from scanner.commands.main import main
from tests.conftest import shared_data

SAMPLE = "real/stereo_calibration_opencv_sample"
BOARD = ["--board", "chessboard", "--board-size", "10x7", "--board-spacing", "0.025"]
PAIRS = 5


def _calibrate(folder, out, *extra):
    return main(["calibrate", "--offline", str(folder), *BOARD, "--out", str(out), *extra])


def _first_images(folder, count):
    """The first `count` images of a folder, in name order."""
    return sorted(folder.iterdir())[:count]


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("cams")
    for side in ("left", "right"):
        (root / "pairs" / side).mkdir(parents=True)
        for image in _first_images(shared_data(SAMPLE) / side, PAIRS):
            shutil.copy(image, root / "pairs" / side / image.name)
    assert _calibrate(root / "pairs", root / "out") == 0
    return root / "out" / "results"


def test_stereo_sample_is_calibrated_without_robot_poses(sample_run):
    report = json.loads((sample_run / "report.json").read_text())
    # Every board is found (OpenCV's classic detector finds all 26 of the whole sample).
    assert report["boards_found"] == report["images"] == PAIRS
    assert report["boards_found_right"] == PAIRS
    # OpenCV 4.x on this sample: 0.22-0.29 px depending on flags.
    assert report["stereo_rms_px"] <= 0.30
    # Rectified corners on the same row: SGBM searches along rows.
    assert report["epipolar_median_px"] < 0.15 and report["epipolar_p95_px"] < 0.5
    # The sample's reference focal length is ~534 px; |T| is ~3.34 squares (25 mm here).
    assert all(520 < f < 548 for f in report["focal_px"])
    assert report["baseline_m"] == pytest.approx(3.34 * 0.025, rel=0.03)
    assert 0.2 < report["board_coverage"] < 1.0
    assert len(report["per_image"]) == PAIRS
    calibration = load_calibration(sample_run / "calibration.yaml")
    assert calibration.stereo is not None
    assert calibration.stereo.baseline_m == pytest.approx(report["baseline_m"])
    assert "not calibrated" in calibration.quality["hand_eye"]
    text = (sample_run / "report.txt").read_text()
    assert "rectified epipolar error" in text and "baseline" in text


def _copy_sample(tmp_path, drop_right=None):
    folder = tmp_path / "pairs"
    shutil.copytree(shared_data(SAMPLE) / "left", folder / "left")
    shutil.copytree(shared_data(SAMPLE) / "right", folder / "right")
    if drop_right:
        (folder / "right" / drop_right).unlink()
    return folder


def _error(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert "Traceback" not in "\n".join(lines)
    return lines[-1]


def test_a_missing_partner_is_named(tmp_path, capsys):
    folder = _copy_sample(tmp_path, drop_right="right07.jpg")
    assert _calibrate(folder, tmp_path / "out") == 2
    message = _error(capsys)
    assert "left07.jpg" in message and "13" in message and "12" in message
    assert not (tmp_path / "out" / "results").exists()


def test_a_different_image_size_is_named(tmp_path, capsys):
    folder = _copy_sample(tmp_path)
    image = cv2.imread(str(folder / "right" / "right03.jpg"))
    cv2.imwrite(str(folder / "right" / "right03.jpg"), cv2.resize(image, (320, 240)))
    assert _calibrate(folder, tmp_path / "out") == 2
    message = _error(capsys)
    assert "right03.jpg" in message and "320x240" in message


def test_no_board_anywhere_says_why(tmp_path, capsys):
    folder = tmp_path / "blank"
    folder.mkdir()
    for k in range(4):
        cv2.imwrite(str(folder / f"img{k}.png"), np.full((480, 640), 128, np.uint8))
    assert _calibrate(folder, tmp_path / "out") == 2
    message = _error(capsys)
    assert "not found in any of the 4 images" in message and "no contrast" in message


def test_a_wrong_board_size_says_what_was_seen(tmp_path, capsys):
    folder = tmp_path / "mono"
    folder.mkdir()
    for image in _first_images(shared_data(SAMPLE) / "left", 3):
        shutil.copy(image, folder / image.name)
    out = tmp_path / "out"
    args = ["calibrate", "--offline", str(folder), "--board", "chessboard"]
    args += ["--board-size", "9x7", "--board-spacing", "0.025", "--out", str(out)]
    assert main(args) == 2
    message = _error(capsys)
    # A 9x7-square board (8x6 inner corners) is found inside the 10x7 one; the larger grid
    # gives it away.
    assert "more squares than given" in message and "9x6 inner corners" in message
    assert not (out / "results").exists()

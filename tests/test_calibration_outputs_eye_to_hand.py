"""`scanner calibrate --eye-to-hand` keeps its marker frames and robot poses; `--eye-to-hand
--offline DIR` solves again from them and reproduces the static camera's pose.

A reduced set (8 grid points, 4 held-out, 4 frames each) keeps the rendering short; the
pipeline is the product's."""

from dataclasses import replace

import cv2
import numpy as np
import pytest
import yaml

from reconstruction.common.transforms import pose_difference
from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.eye_to_hand import run_eye_to_hand
from scanner.calibrate.eye_to_hand_store import MANIFEST, WINDOW_HALF_PX
from scanner.commands.main import main


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    config = CalibrateConfig()
    e2h = replace(config.eye_to_hand, grid_spacing_m=0.2, held_out=4, frames=4)
    out = tmp_path_factory.mktemp("e2h") / "run"
    report = run_eye_to_hand(replace(config, eye_to_hand=e2h), out)
    return out, report


def _X_WS(results):
    return np.array(yaml.safe_load((results / "eye_to_hand.yaml").read_text())["X_WS"])


def test_frames_and_poses_are_kept_in_the_output_folder(recorded):
    out, report = recorded
    assert (out / MANIFEST).is_file()
    points = sorted((out / "points").iterdir())
    assert len(points) == report["fit_points_used"] + report["fit_points_rejected"] + 4
    for folder in points:
        for side in ("left", "right"):
            image = cv2.imread(str(folder / f"{side}.png"), cv2.IMREAD_GRAYSCALE)
            assert image.shape == (4 * 2 * WINDOW_HALF_PX, 2 * WINDOW_HALF_PX)  # 4 frames
        X_WF = np.loadtxt(folder / "pose.txt")
        assert X_WF.shape == (4, 4) and np.allclose(X_WF[3], [0, 0, 0, 1])


def test_offline_solve_reproduces_the_static_camera_pose(recorded, tmp_path, capsys):
    out, report = recorded
    first = _X_WS(out / "results")
    # The run itself is accurate against the simulator's truth.
    truth = np.array(yaml.safe_load((out / MANIFEST).read_text())["truth"]["X_WS"])
    assert pose_difference(first, truth)[0] < 3e-3
    assert main(["calibrate", "--eye-to-hand", "--offline", str(out)]) == 0
    assert "eye-to-hand:" in capsys.readouterr().out
    again = _X_WS(out / "results-2")  # the first result is kept
    dt, dr = pose_difference(again, first)
    assert dt < 1e-9 and dr < 1e-9
    second = yaml.safe_load((out / "results-2" / "eye_to_hand_report.json").read_text())
    for key, value in report["held_out"].items():
        assert second["held_out"][key] == pytest.approx(value, rel=1e-9)
    assert second["truth"] == pytest.approx(report["truth"])


def test_offline_eye_to_hand_refuses_pose_options_and_other_folders(recorded, tmp_path, capsys):
    out, _ = recorded
    assert main(["calibrate", "--eye-to-hand", "--offline", str(out), "--length-unit", "mm"]) == 2
    assert "give no pose options" in capsys.readouterr().err
    assert main(["calibrate", "--eye-to-hand", "--offline", str(tmp_path)]) == 2
    assert "no eye_to_hand_points.yaml" in capsys.readouterr().err

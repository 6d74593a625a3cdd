"""An imported calibration, and any calibration file a command reads, is held to the limits a
computed calibration is refused at (exit 3, nothing written), and an imported one says what was
not measured; a board square size takes a unit."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from reconstruction.calibration import exchange
from reconstruction.calibration.file import Calibration, load_calibration, save_calibration
from reconstruction.common.transforms import make_pose
from reconstruction.stereo.camera_model import StereoCamera, default_stereo_camera
from scanner.commands.main import main
from tests.test_calibration_exchange import _write_filestorage


@pytest.fixture(scope="module")
def stereo() -> StereoCamera:
    return default_stereo_camera()


def _stereo_calib_sample(stereo, folder, square_m: float):
    """What OpenCV's stereo_calib writes: T in board squares of `square_m`, no image size."""
    folder.mkdir()
    _write_filestorage(
        folder / "intrinsics.yml",
        [("M1", stereo.left.K), ("D1", stereo.left.distortion.reshape(1, 5))]
        + [("M2", stereo.right.K), ("D2", stereo.right.distortion.reshape(1, 5))],
    )
    _write_filestorage(
        folder / "extrinsics.yml", [("R", stereo.R), ("T", stereo.T.reshape(3, 1) / square_m)]
    )
    return folder


def test_an_imported_calibration_is_held_to_the_plausibility_limits(stereo, tmp_path, capsys):
    folder = _stereo_calib_sample(stereo, tmp_path / "in_metres", square_m=1.0)
    target = tmp_path / "cal.yaml"
    argv = ["import-calibration", "--format", "opencv", str(folder), "--out", str(target)]
    argv += ["--image-size", "1280x960"]
    # T in metres read in 25 m units: a 3 m baseline and, with the nominal mount, the camera
    # 1.5 m off the flange. Refused as a computed calibration would be, nothing written.
    assert main([*argv, "--length-unit", "25"]) == 3
    (error,) = capsys.readouterr().err.splitlines()
    assert "stereo baseline 3000 mm (limit 500 mm)" in error, error
    assert "mm from the flange (limit 500 mm)" in error and "--length-unit" in error
    assert not target.exists()
    assert main([*argv, "--length-unit", "m"]) == 0
    assert load_calibration(target).stereo.baseline_m == pytest.approx(stereo.baseline_m)


def test_a_square_size_takes_a_unit(stereo, tmp_path):
    folder = _stereo_calib_sample(stereo, tmp_path / "in_squares", square_m=0.025)
    target = tmp_path / "cal.yaml"
    argv = ["import-calibration", "--format", "opencv", str(folder), "--out", str(target)]
    assert main([*argv, "--image-size", "1280x960", "--length-unit", "25mm"]) == 0
    back = load_calibration(target)
    assert back.stereo.baseline_m == pytest.approx(stereo.baseline_m, rel=1e-12)


def test_an_imported_calibration_says_what_was_not_measured(stereo, tmp_path):
    out = tmp_path / "opencv"
    out.mkdir()
    exchange.write_opencv_stereo(stereo, out)
    target = tmp_path / "cal.yaml"
    assert main(["import-calibration", "--format", "opencv", str(out), "--out", str(target)]) == 0
    quality = yaml.safe_load(target.read_text())["quality"]
    assert quality, "an empty quality reads as if everything were fine"
    assert all(str(v).startswith("not measured") for v in quality.values()), quality
    assert "nominal" in quality["hand_eye"]


def test_an_implausible_calibration_file_is_not_exported(stereo, tmp_path, capsys):
    far = make_pose(np.eye(3), [0.0, 0.0, 1.5])  # the camera 1.5 m off the flange
    path = save_calibration(Calibration(far, stereo, stereo.left), tmp_path / "far.yaml")
    out = tmp_path / "exported"
    assert main(["export", str(path), "--format", "ros-tf", "--out", str(out)]) == 3
    (error,) = capsys.readouterr().err.splitlines()
    assert "far.yaml" in error and "1500 mm from the flange" in error
    assert not out.exists()

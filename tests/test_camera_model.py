"""Camera model files: exact YAML round trip and clear errors naming the file and the field."""

import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import (
    StereoCamera,
    default_stereo_camera,
    load_stereo_camera,
    save_stereo_camera,
    stereo_camera_to_dict,
)
from reconstruction.stereo.rectification import compute_rectification


def _calibrated_like() -> StereoCamera:
    """Non-round numbers everywhere, as a calibration would produce them."""
    rng = np.random.default_rng(3)
    base = default_stereo_camera()
    left = type(base.left)(
        base.left.K + np.diag([rng.normal(0, 3), rng.normal(0, 3), 0]),
        base.left.distortion + rng.normal(0, 1e-3, 5),
        1280,
        960,
    )
    angle = 0.01 * rng.standard_normal()
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    return StereoCamera(left, base.right, R, np.array([-0.1200317, 1.3e-4, -7.7e-5]))


def test_yaml_round_trip_is_exact(tmp_path):
    model = _calibrated_like()
    path = tmp_path / "stereo.yaml"
    save_stereo_camera(model, path)
    back = load_stereo_camera(path)
    for a, b in [
        (model.left.K, back.left.K),
        (model.left.distortion, back.left.distortion),
        (model.right.K, back.right.K),
        (model.right.distortion, back.right.distortion),
        (model.R, back.R),
        (model.T, back.T),
    ]:
        assert np.array_equal(a, b)  # bit for bit: YAML floats are written with repr
    assert back.image_size == model.image_size
    # and the derived rectification is therefore identical too
    assert np.array_equal(compute_rectification(model).Q, compute_rectification(back).Q)


def test_file_is_readable_by_a_person(tmp_path):
    path = tmp_path / "stereo.yaml"
    save_stereo_camera(default_stereo_camera(), path)
    text = path.read_text()
    for key in ("schema:", "image_size:", "left:", "right:", "K:", "distortion:", "R:", "T:"):
        assert key in text
    assert yaml.safe_load(text)["T"] == [-0.12, 0.0, 0.0]  # metres


def _write(tmp_path, d) -> str:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(d))
    return str(path)


@pytest.mark.parametrize(
    "edit, needles",
    [
        (lambda d: d.pop("T"), ["missing key 'T'"]),
        (lambda d: d["left"].pop("distortion"), ["left", "missing key 'distortion'"]),
        (lambda d: d.pop("image_size"), ["missing key 'image_size'"]),
        (lambda d: d.update(T=[0.0, 0.0, 0.0]), ["T:", "baseline must be positive"]),
        (lambda d: d.update(T=[0.12, 0.0, 0.0]), ["T:", "+x axis must be positive"]),
        (lambda d: d.update(T=[0.0, -0.12, 0.0]), ["T:", "+x axis must be positive"]),
        (lambda d: d["left"].update(K=[[1, 0], [0, 1]]), ["K:", "shape"]),
        (lambda d: d["right"].update(K="none"), ["K:", "expected numbers"]),
        (lambda d: d.update(image_size=[1280]), ["image_size"]),
        (lambda d: d.update(schema="other/1"), ["schema"]),
    ],
)
def test_bad_files_name_the_file_and_field(tmp_path, edit, needles):
    d = stereo_camera_to_dict(default_stereo_camera())
    edit(d)
    path = _write(tmp_path, d)
    with pytest.raises(ScannerError) as e:
        load_stereo_camera(path)
    message = str(e.value)
    assert path in message
    for needle in needles:
        assert needle in message


def test_unreadable_file(tmp_path):
    with pytest.raises(ScannerError, match="cannot read camera model"):
        load_stereo_camera(tmp_path / "missing.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("left: [unclosed\n")
    with pytest.raises(ScannerError, match="broken.yaml"):
        load_stereo_camera(broken)

"""RGB-D captures: depth counts -> points in the colour frame C through the device's intrinsics,
depth unit and extrinsics, coloured where they project into the colour image; captures stored
losslessly (16-bit depth) and bad ones refused in one line."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import transform_points
from reconstruction.depth.camera_model import (
    DepthDesign,
    camera_model_from_dict,
    camera_model_to_dict,
)
from reconstruction.depth.cloud import rgbd_cloud
from robots.drivers.interfaces import RgbdImages
from scanner.scan_dir.captures import Capture, CaptureStore

DEVICE = DepthDesign().rgbd_camera()


def _plane(z_m: float) -> np.ndarray:
    w, h = DEVICE.depth_size
    return np.full((h, w), round(z_m / DEVICE.depth_scale_m), np.uint16)


def _halves() -> np.ndarray:
    """Colour image: left half red, right half blue (what a wrong extrinsic shifts)."""
    w, h = DEVICE.image_size
    color = np.zeros((h, w, 3), np.uint8)
    color[:, : w // 2] = (255, 0, 0)
    color[:, w // 2 :] = (0, 0, 255)
    return color


def test_a_plane_lifts_into_the_colour_frame_with_its_colours():
    cloud = rgbd_cloud(DEVICE, _plane(0.5), _halves(), 0.3, 0.7)
    # Every point: 0.5 m along D's axis, moved by X_CD (the depth origin 15 mm left of C).
    p_D = transform_points(np.linalg.inv(DEVICE.X_CD), cloud.points_C)
    assert np.allclose(p_D[:, 2], 0.5, atol=1e-12)
    assert np.allclose(cloud.points_C[:, 0] - p_D[:, 0], DEVICE.X_CD[0, 3], atol=1e-12)
    # A point's colour is the colour image's where the point projects (x = 0 in C splits the
    # halves): red left of it, blue right, except the one blended pixel column.
    x = cloud.points_C[:, 0]
    red = (cloud.colors == (255, 0, 0)).all(axis=1)
    blue = (cloud.colors == (0, 0, 255)).all(axis=1)
    f = DEVICE.color.K[0, 0]
    clear = np.abs(x / cloud.points_C[:, 2]) > 1.5 / f
    assert red[clear & (x < 0)].all() and blue[clear & (x > 0)].all()
    # The depth map for fusion: the kept depths on the depth grid, in frame D.
    assert np.allclose(cloud.depth.X_CD, DEVICE.X_CD)
    assert np.count_nonzero(cloud.depth.depth_m) == len(cloud)


def test_depths_outside_the_window_or_the_range_are_dropped_and_the_unit_applies():
    depth = _plane(0.5)
    depth[:, :100] = 0  # no depth
    depth[:, 100:200] = 250  # 0.25 m: nearer than the device measures (0.3 m)
    cloud = rgbd_cloud(DEVICE, depth, _halves(), 0.1, 0.7)
    assert np.all(cloud.pixels_D[:, 0] >= 200)
    assert np.allclose(transform_points(np.linalg.inv(DEVICE.X_CD), cloud.points_C)[:, 2], 0.5)
    assert len(rgbd_cloud(DEVICE, depth, _halves(), 0.55, 0.7)) == 0
    # A calibrated depth correction scales every depth.
    corrected = replace(DEVICE, depth_correction=1.01)
    z = transform_points(
        np.linalg.inv(DEVICE.X_CD), rgbd_cloud(corrected, depth, _halves(), 0.1, 0.7).points_C
    )[:, 2]
    assert np.allclose(z, 0.505)


def test_images_of_other_sizes_or_kinds_are_refused():
    with pytest.raises(ScannerError, match="depth image is 10x10, the depth camera's is 848x480"):
        rgbd_cloud(DEVICE, np.zeros((10, 10), np.uint16), _halves(), 0.3, 0.7)
    with pytest.raises(ScannerError, match="uint16"):
        rgbd_cloud(DEVICE, _plane(0.5).astype(np.float32), _halves(), 0.3, 0.7)
    with pytest.raises(ScannerError, match="colour image is 10x10"):
        rgbd_cloud(DEVICE, _plane(0.5), np.zeros((10, 10, 3), np.uint8), 0.3, 0.7)


def test_the_device_model_round_trips_and_is_told_apart_from_a_stereo_pair():
    from reconstruction.stereo.camera_model import default_stereo_camera

    back = camera_model_from_dict(camera_model_to_dict(DEVICE), "scan.yaml:camera")
    assert np.allclose(back.X_CD, DEVICE.X_CD) and back.depth_scale_m == DEVICE.depth_scale_m
    assert back.depth_baseline_m == DEVICE.depth_baseline_m
    stereo = default_stereo_camera()
    again = camera_model_from_dict(camera_model_to_dict(stereo), "scan.yaml:camera")
    assert again.baseline_m == stereo.baseline_m


def _capture(depth=None, scale=0.001) -> Capture:
    images = RgbdImages(_plane(0.5) if depth is None else depth, scale, _halves(), 1.0)
    return Capture.of(3, 10, np.zeros(6), np.eye(4), images)


def test_an_rgbd_capture_is_stored_losslessly(tmp_path):
    store = CaptureStore.create(tmp_path / "scan", {})
    depth = np.random.default_rng(0).integers(0, 65535, DEVICE.depth_size[::-1], np.uint16)
    store.write_capture(_capture(depth))
    back = store.read_capture(3)
    assert back.sensor == "rgbd" and back.right is None
    assert back.depth.dtype == np.uint16 and np.array_equal(back.depth, depth)
    assert np.array_equal(back.left, _halves()) and back.depth_scale_m == 0.001
    meta = yaml.safe_load((tmp_path / "scan" / "captures" / "0003" / "capture.yaml").read_text())
    assert meta["sensor"] == "rgbd" and meta["depth_size"] == [848, 480]


@pytest.mark.parametrize(
    "change, expected",
    [
        (lambda m: m.pop("depth_scale_m"), "depth_scale_m: expected the depth unit in metres"),
        (lambda m: m.update(depth_scale_m=0), "depth_scale_m: expected a positive number"),
        (lambda m: m.update(depth_size=[10, 10]), "depth image is 848x480, expected 10x10"),
        (lambda m: m.update(sensor="lidar"), "sensor: expected 'stereo', 'rgbd' or 'mono'"),
    ],
)
def test_a_damaged_rgbd_capture_is_one_line(tmp_path, change, expected):
    store = CaptureStore.create(tmp_path / "scan", {})
    store.write_capture(_capture())
    path = tmp_path / "scan" / "captures" / "0003" / "capture.yaml"
    meta = yaml.safe_load(path.read_text())
    change(meta)
    path.write_text(yaml.safe_dump(meta))
    with pytest.raises(ScannerError, match=expected):
        store.read_capture(3)

"""Bad input to the stereo functions: a ScannerError naming the problem, never an empty cloud."""

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import default_stereo_camera
from reconstruction.stereo.cloud import stereo_cloud
from reconstruction.stereo.matching import compute_disparity
from reconstruction.stereo.params import StereoParams, disparity_window, object_depth_window
from reconstruction.stereo.rectification import compute_rectification

GREY = np.zeros((96, 128), np.uint8)


@pytest.mark.parametrize(
    "left, right, needles",
    [
        (GREY, np.zeros((96, 120), np.uint8), ["left image is 128x96", "right image is 120x96"]),
        (np.zeros((96, 128, 4), np.uint8), GREY, ["left image", "4 channels"]),
        (GREY, np.zeros((96, 128, 2), np.uint8), ["right image", "2 channels"]),
        (GREY.astype(np.float32), GREY, ["left image", "uint8"]),
        (GREY, np.zeros((2, 96, 128, 3), np.uint8), ["right image", "4 dimensions"]),
    ],
)
def test_bad_images(left, right, needles):
    with pytest.raises(ScannerError) as e:
        compute_disparity(left, right, 0, 16)
    for needle in needles:
        assert needle in str(e.value)


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        ({"num_disparities": 20}, "multiple of 16"),
        ({"num_disparities": 0}, "positive integer"),
        ({"num_disparities": 128}, "does not fit a 128 px wide image"),
        ({"block_size": 5}, "unknown parameter(s) ['block_size']"),
        ({"block_size_px": 4}, "stereo.block_size_px: must be an odd"),
        ({"mode": "BM"}, "stereo.mode: 'BM' is not one of"),
        ({"p1": 500, "p2": 100}, "0 < p1 < p2"),
        ({"texture_min_std_levels": -1.0}, "stereo.texture_min_std_levels"),
        ({"disp12_max_diff_px": 0}, "stereo.disp12_max_diff_px"),
        ({"lr_check_max_diff_px": 0.0}, "stereo.lr_check_max_diff_px"),
        ({"subsample_step_px": 0}, "stereo.subsample_step_px"),
    ],
)
def test_bad_parameters(kwargs, needle):
    args = {"num_disparities": 16, **kwargs}
    num = args.pop("num_disparities")
    with pytest.raises(ScannerError) as e:
        compute_disparity(GREY, GREY, 0, num, **args)
    assert needle in str(e.value)


def test_bad_depth_windows():
    with pytest.raises(ScannerError, match="0 < z_min < z_max"):
        disparity_window(0.6, 0.4, 1320.0, 0.12)
    with pytest.raises(ScannerError, match="0 < z_min < z_max"):
        disparity_window(0.0, 0.4, 1320.0, 0.12)
    with pytest.raises(ScannerError, match="baseline"):
        disparity_window(0.4, 0.6, 1320.0, -0.12)
    with pytest.raises(ScannerError, match="radius"):
        object_depth_window(0.5, 0.6)


def test_raw_pair_of_the_wrong_size_for_the_camera_model():
    rect = compute_rectification(default_stereo_camera())
    small = np.zeros((480, 640, 3), np.uint8)
    with pytest.raises(ScannerError, match="camera model expects 1280x960"):
        stereo_cloud(rect, small, small, 0.4, 0.6, StereoParams())

"""check-cell's image items on real camera images: a sharp, well exposed pair passes; the same
pair far out of focus, over-exposed or under-exposed fails the item it should, and only it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from robots.drivers.interfaces import StereoImages
from scanner.check_cell.check import ImageLimits, image_items
from tests.conftest import shared_data


def real_pair() -> StereoImages:
    folder = shared_data("real/stereo_calibration_opencv_sample")
    left = cv2.cvtColor(cv2.imread(str(folder / "left" / "left01.jpg")), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(folder / "right" / "right01.jpg")), cv2.COLOR_BGR2RGB)
    return StereoImages(left, right, 0.0)


def verdicts(pair: StereoImages) -> dict[str, bool]:
    out: dict[str, bool] = {}
    for item in image_items(pair, ImageLimits(), None):
        out[item.name] = out.get(item.name, True) and item.ok
    return out


def both(pair: StereoImages, change) -> StereoImages:
    return StereoImages(change(pair.left), change(pair.right), pair.stamp_s)


def test_a_sharp_well_exposed_real_pair_passes():
    assert verdicts(real_pair()) == {"exposure": True, "sharpness": True}


@pytest.mark.parametrize(
    "change, failing",
    [
        (lambda im: cv2.GaussianBlur(im, (0, 0), 4), "sharpness"),  # far out of focus
        (lambda im: np.clip(im.astype(int) * 4, 0, 255).astype(np.uint8), "exposure"),
        (lambda im: (im // 8).astype(np.uint8), "exposure"),
    ],
)
def test_a_blurred_or_badly_exposed_pair_fails_that_item(change, failing):
    result = verdicts(both(real_pair(), change))
    assert result[failing] is False
    assert all(ok for name, ok in result.items() if name != failing)


def test_the_board_item_needs_the_board_in_both_images():
    from reconstruction.calibration.boards import BoardSpec

    pair = real_pair()
    # OpenCV's stereo sample shows a 9 x 6 inner-corner chessboard (10 x 7 squares).
    board = BoardSpec(kind="chessboard", cols=10, rows=7, spacing_m=0.025)
    found = {i.name: i for i in image_items(pair, ImageLimits(), board)}
    assert found["board"].ok, found["board"].detail
    blank = StereoImages(pair.left, np.full_like(pair.right, 128), 0.0)
    missing = {i.name: i for i in image_items(blank, ImageLimits(), board)}
    assert not missing["board"].ok and "0 right" in missing["board"].detail


def test_the_opencv_camera_reads_a_real_recorded_pair_that_passes_the_image_checks():
    """The defaults on real images: OpenCV's stereo sample read as a recording (image
    sequences left%02d.jpg / right%02d.jpg) by the OpenCV camera driver, sized as calibrated,
    and its pairs pass exposure and sharpness."""
    from robots.drivers.opencv_stereo import OpenCvStereoCamera
    from robots.drivers.settings import CameraLinkConfig

    folder = shared_data("real/stereo_calibration_opencv_sample")
    settings = CameraLinkConfig(
        left=str(folder / "left" / "left%02d.jpg"), right=str(folder / "right" / "right%02d.jpg")
    )
    with OpenCvStereoCamera(settings, (640, 480)) as camera:
        assert camera.check_size() == (640, 480)
        for _ in range(3):
            pair = camera.capture()
            assert pair.left.shape == pair.right.shape == (480, 640, 3)
            assert all(ok for ok in verdicts(pair).values()), verdicts(pair)

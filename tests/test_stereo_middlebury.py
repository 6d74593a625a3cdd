"""Real images: Middlebury Tsukuba and Venus (already rectified) against their true disparity.

Catches sign, scale and left/right-swap bugs that a simulator shared with the code could hide.
Reference: OpenCV 4.14 StereoSGBM with the README's settings (../shared/.../README.txt).
"""

import cv2
import numpy as np
import pytest

from reconstruction.stereo.matching import compute_disparity
from tests.conftest import shared_data

# scene: left, right, ground truth, GT scale, num_disparities, reference bad % (only where
# SGBM gave a value), reference bad % (holes counted as bad).
SCENES = {
    "tsukuba": ("im3.png", "im4.png", "disp3.pgm", 16, 16, 4.8, 6.6),
    "venus": ("im2.png", "im6.png", "disp2.pgm", 8, 32, 2.0, 10.0),
}
# The README ignores about d_max columns at the left border: no match can exist there.
LEFT_BORDER_PX = 20
BAD_PX = 1.0
# The default drops pixels where its two matching passes (cost paths from above, from below)
# disagree; about half of them are wrong on Tsukuba. So wrong pixels must stay at or below the
# reference's, while holes, counted as wrong in the second rate, may cost a little more.
ALLOWED_EXCESS_HOLES_PERCENT = 1.5


def _rgb(path):
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


@pytest.mark.parametrize("scene", SCENES)
def test_bad_pixel_rate_within_the_opencv_reference(scene):
    left, right, truth, scale, num_d, ref_bad, ref_bad_holes = SCENES[scene]
    folder = shared_data(f"real/stereo_middlebury/{scene}")
    gt = cv2.imread(str(folder / truth), cv2.IMREAD_GRAYSCALE).astype(np.float32) / scale
    # The DEFAULT settings: Middlebury's posters and walls are smooth (grey-level std < 1 over
    # 9x9) but framed by texture at their own depth, which the low-texture filter must keep.
    disparity = compute_disparity(_rgb(folder / left), _rgb(folder / right), 0, num_d)
    evaluated = gt > 0
    evaluated[:, :LEFT_BORDER_PX] = False
    valid = evaluated & np.isfinite(disparity)
    wrong = np.abs(disparity - gt) > BAD_PX
    bad = 100 * wrong[valid].mean()
    bad_with_holes = 100 * (wrong | ~np.isfinite(disparity))[evaluated].mean()
    assert valid.sum() > 0.9 * evaluated.sum()  # measured: 0.959 (tsukuba), 0.902 (venus)
    assert bad <= ref_bad  # measured: 3.87 %, 1.51 % (one pass: 4.76 %, 1.47 %)
    # Measured: 7.8 %, 11.2 % (one pass: 7.3 %, 10.3 %).
    assert bad_with_holes <= ref_bad_holes + ALLOWED_EXCESS_HOLES_PERCENT

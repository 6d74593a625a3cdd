"""The depth maps fused by TSDF lose the pixels the robot/cell removal rejects, decided once per
small cell of space rather than per pixel."""

import numpy as np

from reconstruction.registration.filtering import RegionOfInterest
from reconstruction.registration.views import DepthImage
from reconstruction.surfaces.meshes import DepthView
from reconstruction.surfaces.tsdf import HOOK_CELL_M, masked_depth


def _slanted_plane() -> DepthView:
    # 400 x 300 pixels, f = 1600 px, a plane 0.4-0.6 m deep across the image: 0.25-0.4 mm per
    # pixel, so each HOOK_CELL_M cell holds several pixels.
    h, w = 300, 400
    K = np.array([[1600.0, 0, w / 2], [0, 1600.0, h / 2], [0, 0, 1]])
    depth = np.tile(np.linspace(0.4, 0.6, w, dtype=np.float32), (h, 1))
    depth[:20] = 0  # no data there
    return DepthView(DepthImage(depth, K), np.eye(4), 7)


def _points_W(view: DepthView) -> tuple[np.ndarray, np.ndarray]:
    depth, K = view.depth.depth_m, view.depth.K
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(float)
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], 1), (v, u)


def test_cells_decide_like_the_pixels_except_within_a_cell_of_the_boundary():
    view = _slanted_plane()
    calls = []

    def remove_right_of_plane(p_W, index):
        calls.append((len(p_W), index))
        return p_W[:, 0] < 0.005

    out = masked_depth(view, RegionOfInterest(shape="none"), remove_right_of_plane)
    p, (v, u) = _points_W(view)
    per_pixel = p[:, 0] < 0.005
    kept = out[v, u] > 0
    assert out[:20].max() == 0  # no data stays no data
    np.testing.assert_array_equal(out[v[kept], u[kept]], view.depth.depth_m[v[kept], u[kept]])
    differ = kept != per_pixel
    assert differ.mean() < 0.01
    # Only pixels whose cell straddles the boundary can differ.
    assert np.all(np.abs(p[differ, 0] - 0.005) <= np.sqrt(3) * HOOK_CELL_M)
    # The hook saw fewer points than there are pixels, with the view's index.
    assert calls and calls[0][1] == 7 and calls[0][0] < 0.5 * len(p)


def test_the_region_of_interest_is_applied_per_pixel():
    view = _slanted_plane()
    roi = RegionOfInterest(shape="sphere", center_m=(0.0, 0.0, 0.5), radius_m=0.02)
    out = masked_depth(view, roi, None)
    p, (v, u) = _points_W(view)
    inside = np.linalg.norm(p - [0, 0, 0.5], axis=1) <= 0.02
    assert 0 < inside.sum() < len(inside)
    np.testing.assert_array_equal(out[v, u] > 0, inside)

"""The simulated depth camera: its noise model on synthetic planes (no Drake), then Drake renders
of the true device at the arm's true pose (geometry, frames, colour registration)."""

import dataclasses

import numpy as np
import pytest

from reconstruction.depth.camera_model import DepthDesign
from robots.simulation.depth_camera import (
    DepthNoise,
    SimulatedDepthCamera,
    depth_rms_m,
    noisy_depth_counts,
)

DESIGN = DepthDesign()
# The focal length of an 848-px-wide, 65 deg depth camera (665.6 px).
F_PX = (848 / 2) / np.tan(np.radians(65.0 / 2))
DEFAULT = DepthNoise()
QUIET = DepthNoise(lateral_px=0.0, dark_drop=0.0, flying_share=0.0)


def _plane_depth(size: int, z0_m: float, tilt_deg: float = 0.0) -> np.ndarray:
    """z-depth of a plane through (0, 0, z0) tilted by tilt_deg about the camera's y axis, seen
    by a size x size patch of the F_PX camera (rays within +-size/2/F_PX rad of the axis)."""
    c = (size - 1) / 2
    x = (np.arange(size) - c) / F_PX
    n = np.array([np.sin(np.radians(tilt_deg)), 0.0, -np.cos(np.radians(tilt_deg))])
    z_along = n[2] * z0_m / (n[0] * x + n[2])  # n . (z r) = n . p0 with r = (x, y, 1)
    return np.tile(z_along, (size, 1))


def _counts(depth, grey=None, noise=DEFAULT, seed=0, scale_m=0.001, scale_error=0.0):
    grey = np.full(depth.shape, 128, np.uint8) if grey is None else grey
    rng = np.random.default_rng(seed)
    return noisy_depth_counts(
        depth, grey, F_PX, DESIGN.baseline_m, scale_m, scale_error, 0.3, 3.0, noise, rng
    )


def test_axial_noise_follows_the_white_paper_formula_and_is_unbiased():
    depth = np.full((200, 200), 0.5)
    # A 10 um unit so that quantisation (unit / sqrt(12)) does not add to the spread.
    reported = _counts(depth, noise=QUIET, scale_m=1e-5).astype(float) * 1e-5
    rms = depth_rms_m(0.5, F_PX, DESIGN.baseline_m, 0.08)
    assert rms == pytest.approx(0.08 * 0.25 / (F_PX * 0.055))
    # 40 000 samples: the std estimate is within 1 % of the truth; 15 % is the brief's
    # agreement with the published formula.
    assert reported.std() == pytest.approx(rms, rel=0.15)
    assert abs(reported.mean() - 0.5) < 1e-4  # unbiased to 0.1 mm (standard error 3 um)


def test_depth_scale_error_divides_the_reported_depth():
    reported = _counts(np.full((200, 200), 0.5), noise=QUIET, scale_error=0.01) * 0.001
    assert abs(reported.mean() - 0.5 / 1.01) < 1e-4  # 0.1 mm


def test_counts_are_whole_depth_units_rounded():
    quiet = dataclasses.replace(QUIET, subpixel_px=0.0)
    for z, count in ((0.5004, 500), (0.5006, 501)):
        counts = _counts(np.full((20, 20), z), noise=quiet)
        assert counts.dtype == np.uint16
        assert np.all(counts == count)  # rounded to 1 mm, not truncated


def test_depth_outside_the_range_or_without_surface_is_zero():
    assert np.all(_counts(np.full((50, 50), 0.25)) == 0)  # nearer than 0.3 m
    assert np.all(_counts(np.full((50, 50), 3.5)) == 0)  # further than 3 m
    assert np.all(_counts(np.full((50, 50), 2.0)) > 0)
    for nothing in (0.0, np.nan, np.inf):
        assert np.all(_counts(np.full((50, 50), nothing)) == 0)


def test_grazing_surfaces_lose_their_depth():
    # A 64 px patch spans +-2.7 deg of rays, so 80 deg stays beyond 75 deg and 60 deg below.
    assert np.all(_counts(_plane_depth(64, 0.5, 80.0)) == 0)
    assert np.mean(_counts(_plane_depth(64, 0.5, 60.0)) > 0) > 0.99
    assert np.mean(_counts(_plane_depth(64, 0.5, -60.0)) > 0) > 0.99


def test_depth_edges_have_flying_pixels_only_at_the_edge():
    depth = np.full((200, 200), 0.5)
    depth[:, 100:] = 0.6
    reported = _counts(depth).astype(float) * 0.001
    # Intermediate: more than 10 mm (over 12 axial RMS at 0.6 m) from both surfaces.
    intermediate = (reported > 0.51) & (reported < 0.59)
    rows, cols = np.nonzero(intermediate)
    # 2 edge pixels per row, 30 % flying, 80 % of the mixes more than 10 mm from both ends:
    # about 100 expected.
    assert len(cols) > 50
    # The 0.25 px lateral jitter moves an edge by at most a pixel or two.
    assert cols.min() >= 97 and cols.max() <= 102
    far = np.ones(200, bool)
    far[97:103] = False
    assert np.all(np.abs(reported[:, far] - depth[:, far]) < 0.006)  # 8 RMS at 0.6 m


def test_dark_surfaces_lose_about_half_their_depth():
    depth = np.full((200, 200), 0.5)
    grey = np.full(depth.shape, 200, np.uint8)
    grey[:, :100] = 5
    counts = _counts(depth, grey)
    lost_dark = np.mean(counts[:, :100] == 0)
    # 20 000 dark pixels: the lost share's standard error is 0.35 %; 3 % is ~8 of them.
    assert lost_dark == pytest.approx(0.5, abs=0.03)
    assert np.all(counts[:, 100:] > 0)


# --- Drake renders ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rig():
    from robots.models.workcell import WorkcellConfig
    from robots.simulation.cell import create_simulation
    from robots.simulation.truth import ErrorModel
    from scanner.scan.preview import first_reachable_view

    sim = create_simulation(WorkcellConfig(), "vase", ErrorModel(seed=3))
    truth = dataclasses.replace(sim.truth, rgbd=DESIGN.rgbd_camera())
    camera = SimulatedDepthCamera(
        sim.workcell, truth, sim.robot.true_joint_positions, DESIGN.baseline_m
    )
    sim.robot.teleport(first_reachable_view(sim, 0.5)[1])
    return sim, truth, camera, camera.capture(), camera.ground_truth()


def _back_projected_D(images, rgbd) -> tuple[np.ndarray, np.ndarray]:
    """The valid depth pixels' mask and their points p_DQ (N, 3)."""
    valid = images.depth > 0
    v, u = np.nonzero(valid)
    z = images.depth[valid] * images.depth_scale_m
    K = rgbd.depth.K
    return valid, np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], 1)


def test_capture_has_the_device_sizes_and_types(rig):
    _, truth, camera, images, _ = rig
    assert images.depth.shape == (480, 848) and images.depth.dtype == np.uint16
    assert images.color.shape == (540, 960, 3) and images.color.dtype == np.uint8
    assert images.depth_scale_m == truth.rgbd.depth_scale_m
    with pytest.raises(ValueError, match="rgbd"):
        SimulatedDepthCamera(camera._cell, dataclasses.replace(truth, rgbd=None), None, 0.055)


def test_depth_lies_on_the_true_object(rig):
    sim, truth, _, images, gt = rig
    obj = gt.object_mask
    assert obj.sum() > 20_000  # the 0.2 m vase at ~0.45 m covers a tenth of the image
    valid = images.depth > 0
    assert (valid & obj).sum() > 0.8 * obj.sum()  # most object pixels have depth
    m = valid & obj
    err = images.depth[m] * images.depth_scale_m - gt.depth_m[m]
    rms = depth_rms_m(gt.depth_m[m], truth.rgbd.depth.K[0, 0], DESIGN.baseline_m, 0.08)
    # Per pixel |error| / RMS: a Gaussian's median is 0.67; 3 leaves room for the 1 mm units
    # and the lateral jitter on slopes, and none for a misplaced camera.
    assert np.median(np.abs(err) / rms) < 3.0

    # Independently of ground_truth(): the points moved to W by X_WC @ X_CD lie on the true
    # mesh (a depth camera rendered at X_WC @ inv(X_CD) would put them 30 mm off).
    import open3d as o3d

    from robots.simulation.cell import object_vertices_W

    valid, p_DQ = _back_projected_D(images, truth.rgbd)
    on_object = obj[valid]
    X_WD = gt.X_WC @ truth.rgbd.X_CD
    assert np.allclose(X_WD, gt.X_WD)
    p_WQ = p_DQ[on_object] @ X_WD[:3, :3].T + X_WD[:3, 3]
    scene = o3d.t.geometry.RaycastingScene()
    mesh = sim.object_mesh
    scene.add_triangles(
        object_vertices_W(mesh, truth.X_WO).astype(np.float32), mesh.triangles.astype(np.uint32)
    )
    distance = scene.compute_distance(o3d.core.Tensor(p_WQ.astype(np.float32))).numpy()
    assert np.median(distance) < 0.002  # m: a few axial RMS (~0.4 mm at 0.45 m)


def test_colour_image_shows_the_object_where_the_depth_says(rig):
    from pydrake.math import RigidTransform

    from robots.simulation.stereo_camera import _RenderedCamera

    sim, truth, camera, images, gt = rig
    rgbd = truth.rgbd
    # The object's pixels in the colour camera, from a label render at the true X_WC.
    color_camera = _RenderedCamera(rgbd.color)
    query, sg = camera._query()
    labels = query.RenderLabelImage(
        color_camera.color, sg.world_frame_id(), RigidTransform(gt.X_WC)
    )
    is_object = np.array(labels.data)[..., 0] == sim.workcell.object_label()
    is_object = color_camera.distort(is_object.astype(np.uint8), nearest=True).astype(bool)

    valid, p_DQ = _back_projected_D(images, rgbd)
    p_CQ = p_DQ[gt.object_mask[valid]] @ rgbd.X_CD[:3, :3].T + rgbd.X_CD[:3, 3]
    uv = p_CQ[:, :2] / p_CQ[:, 2:] @ rgbd.color.K[:2, :2].T + rgbd.color.K[:2, 2]
    u, v = np.rint(uv).astype(int).T
    inside = (u >= 0) & (u < rgbd.color.width) & (v >= 0) & (v < rgbd.color.height)
    assert inside.mean() > 0.99
    # Silhouette pixels may fall just off; X_CD applied the wrong way moves every point ~40 px.
    assert is_object[v[inside], u[inside]].mean() > 0.97
    # And the captured colour image has the object's (textured) colours there, not the empty
    # background's uniform colour.
    background = images.color[~is_object]
    colours = images.color[v[inside], u[inside]].astype(float)
    assert np.median(np.abs(colours - np.median(background, axis=0)).sum(axis=1)) > 30

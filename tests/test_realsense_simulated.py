"""The RealSense driver on frames the simulator rendered, through the SDK's real pipeline.

A small RGB-D device whose depth and colour cameras coincide (what a RealSense delivers after
`rs.align`: depth on the colour grid, X_CD = I) looks at the vase in the simulated cell. Its
captures (depth counts in 1 mm units, RGB colour) are fed to a software device and recorded
(see tests/realsense_recording.py for why a recording: a pipeline cannot run on a live
software device in pyrealsense2 2.59); the driver streams the recording with `rs.pipeline`,
`rs.align` and `wait_for_frames`, and what it delivers must be what the simulator rendered: the same
colour, the same depth (up to the alignment's edges), the same device model, the same cloud.
"""

from __future__ import annotations

import faulthandler
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from reconstruction.depth.camera_model import DepthDesign, RgbdCamera
from robots.drivers.interfaces import CaptureError, RgbdImages
from robots.drivers.realsense import RealSenseCamera
from tests.realsense_recording import FPS, SOFTWARE_ONLY, record

rs = pytest.importorskip("pyrealsense2")

W, H = 160, 120
SERIAL = "SIM-0001"
FRAMES = 12
Z_MIN_M, Z_MAX_M = 0.3, 1.0
# Last resort against an SDK call that never returns (pytest-timeout is not installed): the
# module (simulation, recording, playback, a capture) takes about 10 s, 35 s on a loaded
# two-core machine; past this the process dumps its threads' stacks and exits.
WATCHDOG_S = 300
ATTEMPTS = 3  # fresh playbacks tried when one delivers nothing in time


@pytest.fixture(scope="module", autouse=True)
def _watchdog():
    faulthandler.dump_traceback_later(WATCHDOG_S, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


@dataclass
class Rendered:
    """The simulated device and the captures it rendered of the vase (all at one pose)."""

    model: RgbdCamera
    frames: list[RgbdImages]


@pytest.fixture(scope="module")
def rendered() -> Rendered:
    from robots.models.camera_tool import rig_X_FC
    from robots.models.workcell import WorkcellConfig
    from robots.simulation.cell import create_simulation
    from robots.simulation.truth import ErrorModel
    from scanner.scan.preview import first_reachable_view

    model = DepthDesign(
        depth_width_px=W,
        depth_height_px=H,
        depth_hfov_deg=69.0,
        color_width_px=W,
        color_height_px=H,
        color_hfov_deg=69.0,
        p_DC_m=(0.0, 0.0, 0.0),
    ).rgbd_camera()
    sim = create_simulation(
        WorkcellConfig(), "vase", ErrorModel(seed=3), X_FC_nominal=rig_X_FC(model.X_CR), rgbd=model
    )
    sim.robot.teleport(first_reachable_view(sim, 0.5)[1])
    frames = [sim.camera.capture() for _ in range(FRAMES)]
    for f in frames:
        assert f.depth.shape == (H, W) and f.depth.dtype == np.uint16
        assert f.color.shape == (H, W, 3) and f.color.dtype == np.uint8
        assert f.depth_scale_m == model.depth_scale_m == 0.001
    # The vase fills part of the view (about 1500 pixels have depth), and each capture has its
    # own sensor noise, so a delivered colour image names its capture.
    assert all((f.depth > 0).sum() > 1000 for f in frames)
    colors = {f.color.tobytes() for f in frames}
    assert len(colors) == FRAMES
    return Rendered(model, frames)


@pytest.fixture(scope="module")
def recording(rendered: Rendered, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("realsense_sim") / "vase"
    frames = [(f.depth, f.color) for f in rendered.frames]
    return record(path, frames, rendered.model.color.K, rendered.model.depth_scale_m, SERIAL)


@dataclass
class Delivered:
    """What the driver delivered from the recording: one capture, the index of the fed frame
    pair it is, the device model it reported, and how many playbacks it took."""

    images: RgbdImages
    index: int
    model: RgbdCamera
    attempts: int


@pytest.fixture(scope="module")
def delivered(recording: Path, rendered: Rendered) -> Delivered:
    """One capture through the driver. Playback runs in real time from the moment the pipeline
    starts it (about 0.4 s of frames, no loop): on a loaded machine the pipeline may still be
    starting when the last frame has gone by, so a playback that delivers nothing within the
    timeout is replaced by a fresh one (a few times at most)."""
    failures: list[str] = []
    for attempt in range(1, ATTEMPTS + 1):
        # The context keeps only a weak reference to the playback device: keep it alive.
        context = rs.context(SOFTWARE_ONLY)
        playback = context.load_device(str(recording))
        try:
            with RealSenseCamera(
                serial=SERIAL,
                context=context,
                width_px=W,
                height_px=H,
                fps=FPS,
                min_depth_m=rendered.model.min_depth_m,
                max_depth_m=rendered.model.max_depth_m,
                timeout_s=2.0,
            ) as camera:
                model = camera.rgbd_camera()
                images = camera.capture()
        except CaptureError as e:
            failures.append(str(e))
            continue
        finally:
            del playback
        fed_colors = [f.color.tobytes() for f in rendered.frames]
        color = images.color.tobytes()
        index = fed_colors.index(color) if color in fed_colors else -1
        return Delivered(images, index, model, attempt)
    pytest.fail(f"no capture from {ATTEMPTS} playbacks of the recording: {failures}")


def fed(delivered: Delivered, rendered: Rendered) -> RgbdImages:
    """The fed frame pair whose colour image the driver delivered."""
    assert 0 <= delivered.index < FRAMES, "the delivered colour image is none of the fed ones"
    return rendered.frames[delivered.index]


def test_the_colour_is_a_fed_frame_exactly_in_rgb(delivered: Delivered, rendered: Rendered):
    images = delivered.images
    assert images.color.shape == (H, W, 3) and images.color.dtype == np.uint8
    fed_color = fed(delivered, rendered).color
    assert np.array_equal(images.color, fed_color)
    # RGB, not BGR: the image differs from its channel-swapped self (the vase is not grey).
    assert not np.array_equal(fed_color, fed_color[..., ::-1])


def test_the_depth_is_the_fed_depth_on_the_colour_grid(delivered: Delivered, rendered: Rendered):
    images = delivered.images
    assert images.depth.shape == (H, W) and images.depth.dtype == np.uint16
    assert images.depth_scale_m == pytest.approx(rendered.model.depth_scale_m, rel=1e-6)
    out = images.depth.astype(int)

    def agreement(candidate: np.ndarray) -> float:
        """The share of pixels with depth in both that agree within one count."""
        both = (out > 0) & (candidate > 0)
        return float((np.abs(out - candidate.astype(int))[both] <= 1).mean())

    # The frameset pairs the colour frame with the depth frame of the same time stamp: each
    # capture has its own depth noise (a few counts at 0.5 m), so the others do not agree.
    agreements = [agreement(f.depth) for f in rendered.frames]
    assert int(np.argmax(agreements)) == delivered.index, agreements
    expected = fed(delivered, rendered).depth.astype(int)
    both = (out > 0) & (expected > 0)
    # Identical intrinsics, identity extrinsics: each depth stays where it was, nearly. The SDK
    # writes a depth pixel into the colour pixels between its corners, each rounded after a
    # float32 deprojection and projection, and keeps the nearer depth where two land: now and
    # then (a few of the ~1500 pixels here, seen in one-pixel-wide strips of depth) a depth
    # lands one pixel up or left, taking that pixel's place when nearer, or nowhere. So:
    # nearly all the fed depth survives, nearly all of it unchanged, and every depth delivered
    # is a fed depth of that pixel or of a neighbour.
    assert both.sum() >= 0.9 * (expected > 0).sum()
    assert agreements[delivered.index] >= 0.99
    padded = np.pad(expected, 1)
    for r, c in np.argwhere(out > 0):
        around = padded[r : r + 3, c : c + 3]
        assert np.abs(around[around > 0] - out[r, c]).min() <= 1, (r, c)


def test_the_driver_model_is_the_simulated_device(delivered: Delivered, rendered: Rendered):
    model, sim = delivered.model, rendered.model
    assert model.image_size == sim.image_size == (W, H) and model.depth_size == (W, H)
    # The SDK keeps intrinsics as float32.
    assert np.allclose(model.color.K, sim.color.K, rtol=0, atol=1e-4)
    assert np.allclose(model.depth.K, sim.depth.K, rtol=0, atol=1e-4)
    assert not model.color.distortion.any() and np.array_equal(model.X_CD, sim.X_CD)
    assert model.depth_scale_m == pytest.approx(sim.depth_scale_m, rel=1e-6)
    assert (model.min_depth_m, model.max_depth_m) == (sim.min_depth_m, sim.max_depth_m)


def test_the_delivered_cloud_is_the_simulated_cloud(delivered: Delivered, rendered: Rendered):
    from scipy.spatial import cKDTree

    from reconstruction.depth.cloud import rgbd_cloud

    pair = fed(delivered, rendered)
    images = delivered.images
    sim_cloud = rgbd_cloud(rendered.model, pair.depth, pair.color, Z_MIN_M, Z_MAX_M)
    cloud = rgbd_cloud(delivered.model, images.depth, images.color, Z_MIN_M, Z_MAX_M)
    assert len(sim_cloud.points_C) > 1000
    assert 0.9 * len(sim_cloud.points_C) <= len(cloud.points_C) <= 1.1 * len(sim_cloud.points_C)

    # Each delivered point against the nearest simulated point, and back.
    dist, nearest = cKDTree(sim_cloud.points_C).query(cloud.points_C, distance_upper_bound=0.05)
    back, _ = cKDTree(cloud.points_C).query(sim_cloud.points_C, distance_upper_bound=0.05)
    for d in (dist, back):
        assert np.isfinite(d).all()  # nothing 5 cm from the other cloud
        assert np.median(d) < 1e-4 and np.percentile(d, 95) < 2e-3

    # Points within 1.5 mm are the same pixel's (neighbouring pixels' points lie over 4 mm
    # apart at 0.5 m): the same colour, sampled from the same image.
    matched = dist < 1.5e-3
    assert matched.mean() > 0.98
    colour_error = np.abs(
        cloud.colors[matched].astype(int) - sim_cloud.colors[nearest[matched]].astype(int)
    )
    assert colour_error.max() <= 1

    # Pixel by pixel: a pixel in both clouds is one point, within a depth count along its ray
    # (1 mm in z, at most 1.3x that along the corner pixels' rays) but for the alignment's
    # rare moves.
    sim_at = {tuple(p): i for i, p in enumerate(sim_cloud.pixels_D.astype(int))}
    pixels = [tuple(p) for p in cloud.pixels_D.astype(int)]
    pairs = np.array([(i, sim_at[p]) for i, p in enumerate(pixels) if p in sim_at])
    assert len(pairs) >= 0.9 * len(sim_cloud.points_C)
    ours, theirs = pairs.T
    gap = np.linalg.norm(cloud.points_C[ours] - sim_cloud.points_C[theirs], axis=1)
    assert (gap < 1.5e-3).mean() >= 0.99
    assert np.abs(cloud.colors[ours].astype(int) - sim_cloud.colors[theirs]).max() <= 1

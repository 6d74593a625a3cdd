"""An imported recording's views turned into the reconstruction's input: the working volume,
the view pairs and each pair's cloud in its reference camera's frame.

One camera moved between views: each view is the reference of pairs with its nearest usable
neighbours (`two_view.pairing`; two by default), whose clouds come from the product's own matcher
(`two_view.cloud`). A cloud's pose is the reference view's, so everything after them (the
filter, registration, fusion, surfaces) is what a scan of this product runs.
"""

from __future__ import annotations

import logging
import os
import statistics
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.depth.camera_model import RgbdCamera
from reconstruction.depth.cloud import DepthCloud, view_rgbd_cloud
from reconstruction.registration.views import ViewCloud
from reconstruction.stereo.camera_model import PinholeCamera
from reconstruction.two_view.cloud import PairCloud, pair_cloud
from reconstruction.two_view.pairing import ViewPair, pair_views
from reconstruction.two_view.scaling import downscaled_camera
from reconstruction.working_volume.volume import (
    PosedCamera,
    WorkingVolume,
    volume_from_common_view,
    volume_from_masks,
    volume_of_box,
)
from robots.sensors import sensor_named
from scanner.recordings.settings import RecordingProcessing
from scanner.scan_dir.manifest import SavedScan

log = logging.getLogger("scanner.recordings")

# A used mask keeps the points whose pixel lies within this many pixels of it: hand-drawn
# outlines are off by a pixel or two, and a point on the rim must not be cut by that.
MASK_MARGIN_PX = 3


@dataclass(frozen=True, eq=False)
class RecordedViews:
    """The recording's captures, in capture order: RGB images, masks (None where the recording
    has none), each view's camera, its camera pose X_WC and flange pose X_WF (X_WC when the
    recording gave camera poses), and the capture indices."""

    indices: tuple[int, ...]
    images: tuple[np.ndarray, ...]
    masks: tuple[np.ndarray | None, ...]
    cameras: tuple[PinholeCamera, ...]
    X_WC: tuple[np.ndarray, ...]
    X_WF: tuple[np.ndarray, ...]
    # Depth counts on the image's grid and their unit (m per count), where the recording has them.
    depths: tuple[np.ndarray | None, ...]
    depth_scales_m: tuple[float, ...]

    def posed(self, k: int) -> PosedCamera:
        c = self.cameras[k]
        return PosedCamera(c.K, self.X_WC[k], c.width, c.height)


def read_recorded_views(scan: SavedScan) -> RecordedViews:
    """Every capture of an imported recording; a damaged one is an error naming it (a
    recording is imported whole and checked, so damage is not a view to skip)."""
    indices, images, masks, cameras, X_WC, X_WF, depths, scales = ([] for _ in range(8))
    files = sensor_named(scan.sensor).capture_format  # mono: one image, its camera and pose
    for index in scan.store.captured_indices():
        capture = scan.store.read_capture(index)
        if capture.sensor != files:
            raise ScannerError(f"{scan.root}: capture {index} is {capture.sensor}, not {files}")
        indices.append(index)
        images.append(capture.left)
        masks.append(None if capture.mask is None else capture.mask > 0)
        cameras.append(capture.camera)
        X_WC.append(capture.X_WC)
        X_WF.append(capture.X_WF)
        depths.append(capture.depth)
        scales.append(float(capture.depth_scale_m))
    if len(indices) < 2:
        raise ScannerError(f"{scan.root}: {len(indices)} captures; two views make the first pair")
    return RecordedViews(*map(tuple, (indices, images, masks, cameras, X_WC, X_WF, depths, scales)))


def mask_used(settings: RecordingProcessing, k: int) -> bool:
    """Whether view k's mask (when it has one) restricts the clouds."""
    return settings.masks == "all" or (settings.masks == "even" and k % 2 == 0)


def working_volume(views: RecordedViews, settings: RecordingProcessing) -> WorkingVolume:
    """The sphere (or box) the object lies in: given, else the hull of the masks used, else the
    sphere every view holds whole about the cameras' common point."""
    if settings.volume_box_m is not None:
        return volume_of_box(settings.volume_box_m[:3], settings.volume_box_m[3:])
    if settings.volume_centre_m is not None:
        return WorkingVolume(np.array(settings.volume_centre_m), settings.volume_radius_m, "given")
    cameras = [views.posed(k) for k in range(len(views.indices))]
    common = volume_from_common_view(cameras)
    used = [k for k, m in enumerate(views.masks) if m is not None and mask_used(settings, k)]
    if not used:
        return common
    return volume_from_masks([cameras[k] for k in used], [views.masks[k] for k in used], common)


def footprint_m(views: RecordedViews, volume: WorkingVolume, downscale: float) -> float:
    """The median size of one (downscaled) pixel on the object at the working distance: what
    the grids of the filter, the fused cloud and the surfaces are sized from."""
    sizes = []
    for camera, X_WC in zip(views.cameras, views.X_WC, strict=True):
        f = downscaled_camera(camera, downscale).K[0, 0]
        sizes.append(float(np.linalg.norm(volume.centre_W - X_WC[:3, 3])) / f)
    return statistics.median(sizes)


def hull_keep(views: RecordedViews, settings: RecordingProcessing):
    """A `remove_points` hook keeping the points inside every used mask's cone (a few pixels
    wider), or None without masks: the masks' visual hull as the region of interest, also for
    the views whose own masks are not used."""
    used = [k for k, m in enumerate(views.masks) if m is not None and mask_used(settings, k)]
    if not used:
        return None
    kernel = cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * MASK_MARGIN_PX + 1, 2 * MASK_MARGIN_PX + 1)
    )
    grown = [cv2.dilate(views.masks[k].astype(np.uint8), kernel) > 0 for k in used]
    cameras = [views.posed(k) for k in used]

    def keep(p_W: np.ndarray) -> np.ndarray:
        out = np.ones(len(p_W), bool)
        for camera, mask in zip(cameras, grown, strict=True):
            p_C = transform_points(invert(camera.X_WC), p_W)
            z = p_C[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = np.floor(p_C[:, 0] / z * camera.K[0, 0] + camera.K[0, 2] + 0.5).astype(int)
                v = np.floor(p_C[:, 1] / z * camera.K[1, 1] + camera.K[1, 2] + 0.5).astype(int)
            seen = (z > 0) & (u >= 0) & (v >= 0) & (u < camera.width) & (v < camera.height)
            inside = np.ones(len(p_W), bool)
            inside[seen] = mask[v[seen], u[seen]]
            out &= inside
        return out

    return keep


@dataclass(frozen=True, eq=False)
class PairedClouds:
    """The views' clouds in order, each with its reference view (whose frame C it is in) and
    its pair (None: the view's own depth image), and the views made of them for the pipeline:
    view k is cloud k, with its reference view's flange pose."""

    references: tuple[int, ...]
    pairs: tuple[ViewPair | None, ...]
    clouds: tuple[PairCloud | DepthCloud, ...]
    views: tuple[ViewCloud, ...]
    seconds: tuple[float, ...]


def depth_cloud(
    views: RecordedViews, k: int, volume: WorkingVolume, mask: np.ndarray | None
) -> DepthCloud:
    """View k's own depth image as a cloud (the RGB-D path: a depth camera on the image's
    grid), the depths the working volume spans, inside the mask when one is used."""
    camera = views.cameras[k]
    device = RgbdCamera(camera, camera, np.eye(4), views.depth_scales_m[k], 1e-3, 1e3)
    cloud = view_rgbd_cloud(
        device, views.depths[k], views.images[k], views.X_WC[k], volume.centre_W, volume.radius_m
    )
    if mask is None:
        return cloud
    u, v = cloud.pixels_D[:, 0].astype(int), cloud.pixels_D[:, 1].astype(int)
    keep = mask[v, u]
    return DepthCloud(cloud.points_C[keep], cloud.colors[keep], cloud.pixels_D[keep], cloud.depth)


def paired_clouds(
    views: RecordedViews, volume: WorkingVolume, settings: RecordingProcessing
) -> PairedClouds:
    """Every view's cloud: its depth image where it has one, else its pair's, two at a time per
    core (OpenCV's matching and feature search release the GIL)."""
    import time

    n = len(views.indices)
    stereo = [k for k in range(n) if views.depths[k] is None]
    pairs = ()
    if stereo:
        found = pair_views(list(views.X_WC), volume.centre_W, settings.pairing)
        pairs = tuple(p for p in found if p.reference in stereo)
    jobs = sorted(
        [(k, None) for k in range(n) if views.depths[k] is not None]
        + [(p.reference, p) for p in pairs],
        key=lambda job: job[0],
    )

    def one(job: tuple[int, ViewPair | None]):
        t0 = time.perf_counter()
        i, pair = job
        mask = views.masks[i] if views.masks[i] is not None and mask_used(settings, i) else None
        if pair is None:
            return depth_cloud(views, i, volume, mask), time.perf_counter() - t0
        j = pair.other
        cloud = pair_cloud(
            views.images[i],
            views.images[j],
            views.cameras[i],
            views.cameras[j],
            views.X_WC[i],
            views.X_WC[j],
            volume.centre_W,
            volume.radius_m,
            settings.stereo,
            mask,
            settings.two_view,
        )
        return cloud, time.perf_counter() - t0

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        done = list(pool.map(one, jobs))
    out = []
    for k, ((i, pair), (cloud, _)) in enumerate(zip(jobs, done, strict=True)):
        out.append(ViewCloud(k, cloud.points_C, cloud.colors, views.X_WF[i], cloud.depth, float(k)))
        if pair is not None:
            log.info(
                "pair %d-%d: %d points, epipolar %.2f px%s",
                views.indices[i],
                views.indices[pair.other],
                len(cloud.points_C),
                cloud.pose.after.median_px,
                " (pose refined)" if cloud.pose.refined else "",
            )
    return PairedClouds(
        tuple(i for i, _ in jobs),
        tuple(p for _, p in jobs),
        tuple(c for c, _ in done),
        tuple(out),
        tuple(s for _, s in done),
    )

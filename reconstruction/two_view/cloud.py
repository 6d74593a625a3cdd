"""The cloud of one view pair, through the product's stereo machinery.

Reference view i and other view j of one camera, with their poses X_WC (metres): the relative
pose is checked against the images (and refined when it is off: `two_view.epipolar`), the pair
becomes a stereo rig (turned by quarter turns when the baseline is not along +x:
`two_view.rectification`), both images are rectified at the source's resolution, SGBM with
its filters (`stereo.matching.disparity_image`) searches the disparities of the working
volume's depths, and the valid disparities are lifted into the ORIGINAL reference camera frame
C_i, the frame `ViewCloud` expects.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from reconstruction.common.checks import check_fields, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import check_pose, invert, transform_points
from reconstruction.registration.views import DepthImage
from reconstruction.stereo.camera_model import PinholeCamera, project_points
from reconstruction.stereo.cloud import StereoCloud, depth_image, reproject, sample_image
from reconstruction.stereo.matching import disparity_image, grey_image
from reconstruction.stereo.params import StereoParams, disparity_window, object_depth_window
from reconstruction.two_view.epipolar import (
    EpipolarConfig,
    EpipolarError,
    PoseRefinement,
    checked_pose,
    error_of,
    match_features,
)
from reconstruction.two_view.rectification import (
    PairRig,
    pair_rectification,
    pair_rig,
    rectify_views,
    rectifying_rotations,
    rotate_image,
)
from reconstruction.two_view.scaling import downscaled_camera, downscaled_image, downscaled_mask


@dataclass(frozen=True)
class TwoViewConfig:
    """How a view pair is matched. downscale: images (and cameras) are reduced by this factor
    before anything else (1 = full resolution; see `two_view.scaling`). refine_pose: refine the
    relative pose when its epipolar error is above epipolar.max_error_px."""

    downscale: float = positive(1.0)
    refine_pose: bool = True
    epipolar: EpipolarConfig = field(default_factory=EpipolarConfig)

    def __post_init__(self) -> None:
        check_fields("two_view", self)
        if not self.downscale >= 1.0:
            raise ScannerError(f"two_view.downscale: must be at least 1, got {self.downscale}")
        if not isinstance(self.refine_pose, bool):
            raise ScannerError(
                f"two_view.refine_pose: must be true or false, got {self.refine_pose!r}"
            )


@dataclass(frozen=True, eq=False)
class PairCloud:
    """Points of one view pair in the ORIGINAL reference camera frame C_i.

    points_C: (N, 3) float64 metres; colors: (N, 3) uint8 RGB from the reference image.
    depth: the rectified depth of the kept points (on the rectified, possibly turned and
    downscaled grid; its X_CD includes the turn). pose: the relative pose X_CiCj used, with the
    epipolar errors before and after its check. quarter_turns: np.rot90's k of the pair's rig.
    """

    points_C: np.ndarray
    colors: np.ndarray
    depth: DepthImage
    pose: PoseRefinement
    quarter_turns: int

    def __post_init__(self) -> None:
        for a in (self.points_C, self.colors):
            a.setflags(write=False)

    def __len__(self) -> int:
        return len(self.points_C)

    @property
    def epipolar_error(self) -> EpipolarError:
        """The epipolar error of the pose used (after refinement when there was one)."""
        return self.pose.after

    @property
    def refined(self) -> bool:
        return self.pose.refined


def _check_view(image: np.ndarray, camera: PinholeCamera, name: str) -> None:
    if image.shape[1::-1] != (camera.width, camera.height):
        raise ScannerError(
            f"{name} image is {image.shape[1]}x{image.shape[0]} px, its camera expects "
            f"{camera.width}x{camera.height}"
        )


def _masked(cloud: StereoCloud, keep: np.ndarray) -> StereoCloud:
    return StereoCloud(
        cloud.points_C[keep], cloud.colors[keep], cloud.pixels_rect[keep], cloud.pixels_left[keep]
    )


def _inside(camera: PinholeCamera, pixels: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) whose bilinear sample lies wholly within the image."""
    return (
        (pixels[:, 0] >= 0)
        & (pixels[:, 1] >= 0)
        & (pixels[:, 0] <= camera.width - 1)
        & (pixels[:, 1] <= camera.height - 1)
    )


def _seen_by_both(rig: PairRig, cloud_V: StereoCloud) -> np.ndarray:
    """(N,) bool: the point's pixel lies inside the (turned) reference image and its projection
    inside the (turned) other image."""
    stereo = rig.stereo
    p_R = cloud_V.points_C @ stereo.R.T + stereo.T
    return _inside(stereo.left, cloud_V.pixels_left) & _inside(
        stereo.right, project_points(stereo.right, p_R)
    )


def pair_cloud(
    image_i: np.ndarray,
    image_j: np.ndarray,
    cam_i: PinholeCamera,
    cam_j: PinholeCamera,
    X_WC_i: np.ndarray,
    X_WC_j: np.ndarray,
    p_W_centre: np.ndarray,
    radius_m: float,
    params: StereoParams,
    mask_i: np.ndarray | None = None,
    config: TwoViewConfig | None = None,
) -> PairCloud:
    """The cloud of reference view i and other view j of an object within radius_m of
    p_W_centre (W, metres).

    image_i, image_j: uint8 RGB or grey images as the cameras gave them (cam_i, cam_j: their
    intrinsics and distortion). X_WC_i, X_WC_j: camera poses (4x4). params: the SGBM settings
    (real images may need others than the simulator's defaults). mask_i: optional (H, W) bool
    region of interest in the reference image; only points whose reference pixel is inside it
    are kept. config: downscaling and the pose check.
    """
    config = config or TwoViewConfig()
    _check_view(image_i, cam_i, "reference")
    _check_view(image_j, cam_j, "other")
    if mask_i is not None and np.asarray(mask_i).shape != image_i.shape[:2]:
        raise ScannerError(
            f"reference mask is {np.asarray(mask_i).shape[::-1]} px, the image "
            f"{image_i.shape[1::-1]}"
        )
    X_WC_i = check_pose(X_WC_i, "reference X_WC")
    X_WC_j = check_pose(X_WC_j, "other X_WC")
    factor = config.downscale
    cam_i, cam_j = downscaled_camera(cam_i, factor), downscaled_camera(cam_j, factor)
    image_i, image_j = downscaled_image(image_i, factor), downscaled_image(image_j, factor)

    X_CiCj = invert(X_WC_i) @ X_WC_j
    matches = match_features(image_i, image_j, cam_i, cam_j, config.epipolar)
    if config.refine_pose:
        pose = checked_pose(matches, cam_i, cam_j, X_CiCj, config.epipolar)
    else:
        error = error_of(matches, cam_i, cam_j, X_CiCj)
        pose = PoseRefinement(X_CiCj, error, error, False)

    rig = pair_rig(cam_i, cam_j, pose.X_CiCj)
    # The working volume's depth along the rectified optical axis.
    R1 = rectifying_rotations(rig)[0]
    p_V_centre = transform_points(invert(X_WC_i @ rig.X_CV), np.asarray(p_W_centre, float)[None])
    z_min_m, z_max_m = object_depth_window(float((p_V_centre @ R1.T)[0, 2]), radius_m)
    rect = pair_rectification(rig, z_min_m)
    k = rig.quarter_turns
    left, right = rotate_image(image_i, k), rotate_image(image_j, k)
    grey_left, grey_right = rectify_views(
        rect, grey_image(left, "reference"), grey_image(right, "other")
    )
    min_disparity, num_disparities = disparity_window(
        z_min_m, z_max_m, rect.focal_px, rect.baseline_m
    )
    disparity = disparity_image(grey_left, grey_right, min_disparity, num_disparities, params)
    cloud_V = reproject(rect, disparity, left, z_min_m, z_max_m, params.subsample_step_px)

    # SGBM carries disparities into the black corners of the rectified grid (no source pixel
    # there), which the low-texture filter keeps when they continue the image's: only points
    # that both images saw stay.
    cloud_V = _masked(cloud_V, _seen_by_both(rig, cloud_V))
    if mask_i is not None:
        mask = rotate_image(downscaled_mask(mask_i, factor), k).astype(np.uint8)
        inside = sample_image(mask, cloud_V.pixels_left, cv2.INTER_NEAREST) > 0
        cloud_V = _masked(cloud_V, inside)

    depth_V = depth_image(rect, cloud_V)
    colour_rect = cv2.remap(left, *rect.maps_left, cv2.INTER_LINEAR)
    if colour_rect.ndim == 2:
        colour_rect = np.repeat(colour_rect[..., None], 3, axis=2)
    colour_rect = np.where(depth_V.depth_m[..., None] > 0, colour_rect, 0).astype(np.uint8)
    depth = DepthImage(depth_V.depth_m, depth_V.K, rig.X_CV @ depth_V.X_CD, colour_rect)
    points_C = transform_points(rig.X_CV, cloud_V.points_C)
    return PairCloud(points_C, np.array(cloud_V.colors), depth, pose, k)

"""Two views of one camera as a `StereoCamera` that the product's rectification accepts.

`StereoCamera` (and SGBM after it) needs the right camera on the +x side of the left one. Two
arm poses can have their baseline along any direction of the reference camera's image: along
-x (the other view is on the left), along y (the other view is above or below). The images of
both views are then turned by the same quarter turn (np.rot90), which is a pure "virtual
camera" rotation V about the optical axis: no resampling, no loss, and the baseline lies along
+x of V. Points come out in V; `PairRig.X_CV` brings them back into the ORIGINAL reference
camera frame C.

np.rot90(image, 1) moves pixel (u, v) of a W-wide image to (v, W - 1 - u): the new x axis is
the old +y, the new y axis the old -x, so R_CV = Rz(+90 deg) and K becomes
[[fy, 0, cy], [0, fx, W - 1 - cx]]. Distortion turns with the image exactly: the radial terms
(k1, k2, k3) depend on the radius only, and the tangential pair maps as (p1, p2) -> (-p2, p1)
(substitute x = -y', y = x' in OpenCV's model). Skew cannot follow a quarter turn (OpenCV's K
has no K[1, 0]), so a skewed camera is refused when a turn is needed.

What is left after the quarter turn, up to 45 deg of baseline tilt in the image and the
convergence of two views aimed at one centre (about 10 deg on DTU), is rectification's rotation.
`compute_rectification` keeps the input image size and, with alpha = 0, zooms in until no
rectified pixel falls outside either source image: on a DTU pair tilted by 30 deg that is an
8.6x zoom, one pixel in 70 of the view kept (alpha = 1 instead shrinks it by a third).
`pair_rectification` takes stereoRectify's rotations and chooses the rectified cameras itself:
the source focal length, and a grid that holds the reference image plus, on its left, room for
the disparity search (SGBM matches no column left of its search's end); pixels of that grid
outside both images stay black, and points there are dropped (`two_view.cloud`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import (
    invert,
    make_pose,
    matrix_to_rotvec,
    rotvec_to_matrix,
)
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera
from reconstruction.stereo.rectification import Rectification, rectification_of

# Skew dropped by a quarter turn moves a pixel by skew * y (y = (v - cy) / fy, under 0.5 in
# usual lenses): at most 0.005 px at this bound.
MAX_SKEW_PX = 0.01

# R_CV of one quarter turn (np.rot90 with k = 1): x_V = y_C, y_V = -x_C, z_V = z_C.
_R_QUARTER = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class PairRig:
    """A view pair as a stereo rig: `stereo` has the reference view (turned) as its left camera
    and the other view (turned alike) as its right one. quarter_turns: k of np.rot90 applied to
    both images (0..3). X_CV: pose of the turned reference camera V in the original reference
    camera frame C (a rotation about the optical axis)."""

    stereo: StereoCamera
    quarter_turns: int
    X_CV: np.ndarray

    def __post_init__(self) -> None:
        self.X_CV.setflags(write=False)


def quarter_turns_for(p_CO: np.ndarray) -> int:
    """The quarter turns (np.rot90's k) that put the other camera's centre p_CO (in the
    reference camera frame C) on the +x side of the turned frame: the image-plane direction
    of the baseline, +x -> 0, +y -> 1, -x -> 2, -y -> 3. Vertical pairs are as good as
    horizontal ones: a turn costs nothing."""
    x, y = float(p_CO[0]), float(p_CO[1])
    if abs(x) >= abs(y):
        return 0 if x > 0 else 2
    return 1 if y > 0 else 3


def rotate_image(image: np.ndarray, quarter_turns: int) -> np.ndarray:
    """The image turned by np.rot90 (any channel count), contiguous for OpenCV."""
    return np.ascontiguousarray(np.rot90(image, quarter_turns, axes=(0, 1)))


def rotate_camera(camera: PinholeCamera, quarter_turns: int) -> tuple[PinholeCamera, np.ndarray]:
    """(the camera V that sees `rotate_image(image, quarter_turns)`, R_CV (3x3))."""
    k = quarter_turns % 4
    if k and abs(camera.K[0, 1]) > MAX_SKEW_PX:
        raise ScannerError(
            f"camera K: skew K[0][1] = {camera.K[0, 1]:.4g} px cannot follow the image turned "
            f"for a non-horizontal pair; at most {MAX_SKEW_PX} px is accepted"
        )
    K, dist = camera.K.copy(), camera.distortion.copy()
    width, height = camera.width, camera.height
    R_CV = np.eye(3)
    for _ in range(k):
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        K = np.array([[fy, 0.0, cy], [0.0, fx, width - 1 - cx], [0.0, 0.0, 1.0]])
        dist[2], dist[3] = -dist[3], dist[2]
        width, height = height, width
        R_CV = R_CV @ _R_QUARTER
    return PinholeCamera(K, dist, width, height), R_CV


def pair_rig(
    camera_reference: PinholeCamera, camera_other: PinholeCamera, X_CO: np.ndarray
) -> PairRig:
    """The rig of two views: the reference camera (frame C), the other camera (frame O) at
    X_CO (4x4, metres) in C. Both images must be turned by `quarter_turns` before use."""
    if (camera_reference.width, camera_reference.height) != (
        camera_other.width,
        camera_other.height,
    ):
        raise ScannerError(
            f"view pair: the images are {camera_reference.width}x{camera_reference.height} and "
            f"{camera_other.width}x{camera_other.height} px; a pair needs one image size"
        )
    k = quarter_turns_for(X_CO[:3, 3])
    left, R_CV = rotate_camera(camera_reference, k)
    right, _ = rotate_camera(camera_other, k)
    X_CV = make_pose(R_CV, np.zeros(3))
    # Both views turn alike, so the other's turned frame sits at X_CO @ X_CV in C.
    X_VR = invert(X_CV) @ X_CO @ X_CV
    X_RV = invert(X_VR)
    return PairRig(StereoCamera(left, right, X_RV[:3, :3], X_RV[:3, 3]), k, X_CV)


def _border_px(camera: PinholeCamera, step_px: int = 4) -> np.ndarray:
    """(N, 1, 2) pixels along the image border (every step_px), for footprints."""
    w, h = camera.width - 1, camera.height - 1
    us, vs = (
        np.arange(0, w + step_px, step_px).clip(0, w),
        np.arange(0, h + step_px, step_px).clip(0, h),
    )
    border = np.concatenate(
        [
            np.stack([us, np.zeros_like(us)], 1),
            np.stack([us, np.full_like(us, h)], 1),
            np.stack([np.zeros_like(vs), vs], 1),
            np.stack([np.full_like(vs, w), vs], 1),
        ]
    )
    return border.astype(np.float64).reshape(-1, 1, 2)


def _footprint(camera: PinholeCamera, R_rect: np.ndarray, focal_px: float) -> np.ndarray:
    """(min_u, min_v, max_u, max_v) of the camera's image on a rectified grid of focal length
    focal_px whose principal point is at (0, 0)."""
    P = np.array([[focal_px, 0, 0], [0, focal_px, 0], [0, 0, 1]])
    uv = cv2.undistortPoints(_border_px(camera), camera.K, camera.distortion, R=R_rect, P=P)
    return np.concatenate([uv[:, 0].min(axis=0), uv[:, 0].max(axis=0)])


def rectifying_rotations(rig: PairRig) -> tuple[np.ndarray, np.ndarray, float]:
    """(R1, R2, baseline_m) of the pair's rectification: the rotations from the turned frames
    V and O' to the rectified ones (which do not depend on the rectified grid), always with
    the baseline along x.

    This is stereoRectify's construction (Bouguet's: both cameras turned by half the relative
    rotation, then a common rotation puts the baseline on the x axis) without its choice of
    axis: stereoRectify rectifies vertically when the half-turned baseline's |y| is not below
    its |x|, which a baseline near the image's diagonal reaches although the quarter turn put
    it on x (DTU's views 10 and 13: 42 deg, and 10 deg of roll between them). Its rectified
    baseline along x was then zero. Elsewhere the result is stereoRectify's."""
    model = rig.stereo
    r_r = rotvec_to_matrix(-0.5 * matrix_to_rotvec(model.R))
    t = r_r @ model.T
    norm_t = float(np.linalg.norm(t))
    uu = np.array([1.0 if t[0] > 0 else -1.0, 0.0, 0.0])
    ww = np.cross(t, uu)
    norm_w = float(np.linalg.norm(ww))
    if norm_w > 0.0:
        ww *= math.acos(min(abs(t[0]) / norm_t, 1.0)) / norm_w
    wR = rotvec_to_matrix(ww)
    R1, R2 = wR @ r_r.T, wR @ r_r
    return R1, R2, float(-(R2 @ model.T)[0])


# Beyond f b / z_min, the SGBM search reaches up to this many more pixels: the 2 px margin of
# `disparity_window` and its rounding up to a multiple of 16.
_SEARCH_MARGIN_PX = 18


def pair_rectification(rig: PairRig, z_min_m: float, max_growth: float = 3.0) -> Rectification:
    """The rectification of a view pair at the source's resolution (see the module docstring),
    for matching depths from z_min_m (rectified frame) on.

    The rectified focal length is the mean of the two source focal lengths. SGBM leaves the
    first min_disparity + num_disparities columns of the left image without a match (their
    search would leave the right image), and two views aimed at one centre with zero disparity
    at infinity see the working volume at large disparities (about a third of the image width
    on DTU pairs). So the grid starts that far left of the
    reference image, over the other image's part there, and ends with the reference image; it
    holds the rows both images share. The record is the product's `Rectification`, whose
    `image_size` is that of the rectified grid (not the source's); `rectify_views` resamples the
    images onto it. A grid more than max_growth times the source's width or height means views
    that hardly overlap: refused.
    """
    if not z_min_m > 0:
        raise ScannerError(f"view pair: the nearest depth must be positive, got {z_min_m} m")
    model = rig.stereo
    L, R = model.left, model.right
    R1, R2, baseline_m = rectifying_rotations(rig)
    f = float(np.mean([L.K[0, 0], L.K[1, 1], R.K[0, 0], R.K[1, 1]]))
    left, right = _footprint(L, R1, f), _footprint(R, R2, f)
    u0 = left[0] - (math.ceil(f * baseline_m / z_min_m) + _SEARCH_MARGIN_PX)
    v0 = max(left[1], right[1])
    u1, v1 = left[2], min(left[3], right[3])
    width, height = int(math.ceil(u1 - u0)) + 1, int(math.ceil(v1 - v0)) + 1
    limit_w, limit_h = max_growth * L.width, max_growth * L.height
    if not (8 <= width <= limit_w and 8 <= height <= limit_h):
        raise ScannerError(
            f"view pair: the views share a rectified area of {width}x{height} px for "
            f"{L.width}x{L.height} px images; they overlap too little to be a stereo pair"
        )
    cx, cy = -math.floor(u0), -math.floor(v0)
    # Rectified cameras with CALIB_ZERO_DISPARITY: one principal point, the right camera at
    # -Tx = baseline along x.
    Tx = -baseline_m
    P1 = np.array([[f, 0, cx, 0], [0, f, cy, 0], [0, 0, 1, 0]], float)
    P2 = P1.copy()
    P2[0, 3] = f * Tx
    Q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, -1 / Tx, 0]], float)
    return rectification_of(L, R, R1, R2, P1, P2, Q, (width, height))


def rectify_views(
    rect: Rectification, left: np.ndarray, right: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The (turned) reference and other images resampled onto the rectified grid, any channel
    count; pixels without a source are 0."""
    return (
        cv2.remap(left, *rect.maps_left, cv2.INTER_LINEAR),
        cv2.remap(right, *rect.maps_right, cv2.INTER_LINEAR),
    )

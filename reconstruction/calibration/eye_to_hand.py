"""Eye-to-hand calibration (static stereo camera S, marker on the flange), after the KTH report.

Rodhain (KTH 2008, seeds/004) calibrated a static stereo camera against a robot by driving a
blinking LED on the hand over a 3D grid: the LED is found by frame differencing (|I(t+1) - I(t)|
above T = 20 grey levels), temporal summation over 20 frames, a 3x3 box filter and a threshold at
80 % of the maximum, then the mean pixel position; the stereo pair is triangulated, and the rigid
camera-to-robot transform is solved by least squares, dropping the worst point while it is
farther than a threshold. Its evaluation on random held-out points reached ~8 mm mean error.

Differences here (each a parameter): the centre is the centroid of the marker's silhouette in
the mean difference image, edge pixels weighted by coverage (the plain mean of thresholded pixels
is quantised to ~0.5 px; a brightness-weighted mean follows the shading); the fit is the
closed-form least-squares rigid transform (Kabsch/Umeyama) instead of a pseudo-inverse over an
affine matrix, so the result is always a rotation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, transform_points
from reconstruction.stereo.camera_model import StereoCamera


@dataclass(frozen=True)
class MarkerDetectionSettings:
    """KTH values: T = 20 grey levels, a 3x3 box filter, 80 % of the maximum; plus the sub-pixel
    centroid's saturation (see below)."""

    difference_threshold: float = positive(20.0)
    box_filter_px: int = integer(3)
    accept_fraction: float = 0.8
    min_pixels: int = integer(3)
    # Mean frame difference (grey levels) above which a pixel counts fully in the centroid; below
    # it, in proportion (anti-aliased edge). The centre is the silhouette's, not the shading's:
    # a lit sphere is brighter towards its light, which shifted a difference-weighted centroid
    # by 0.3-0.6 px (2.3 mm of depth at 1 m) in the simulator.
    saturation_grey: float = positive(60.0)

    def __post_init__(self) -> None:
        section = "eye_to_hand.detection"
        check_fields(section, self)
        if not 0 < self.accept_fraction <= 1:
            raise ScannerError(f"{section}.accept_fraction: must be in (0, 1]")


@dataclass(frozen=True)
class MarkerDetection:
    """Marker centre (px, OpenCV convention), the blob size (px) and its summed score."""

    u: float
    v: float
    pixels: int
    peak: float


def detect_blinking_marker(
    frames: Sequence[np.ndarray], settings: MarkerDetectionSettings = MarkerDetectionSettings()
) -> MarkerDetection | None:
    """The blinking marker in consecutive grey frames of a still scene, or None."""
    if len(frames) < 2:
        raise ScannerError("blinking-marker detection needs at least 2 frames")
    stack = [
        f.astype(np.float32)
        if f.ndim == 2
        else cv2.cvtColor(f, cv2.COLOR_RGB2GRAY).astype(np.float32)
        for f in frames
    ]
    count = np.zeros_like(stack[0])
    weight = np.zeros_like(stack[0])
    for a, b in zip(stack[:-1], stack[1:]):
        diff = np.abs(b - a)
        count += diff > settings.difference_threshold
        weight += diff
    k = settings.box_filter_px
    filtered = cv2.boxFilter(count, -1, (k, k), normalize=False)
    peak = float(filtered.max())
    if peak <= 0:
        return None
    mask = filtered >= settings.accept_fraction * peak
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n < 2:
        return None
    # The strongest component is the marker; other blinking spots would be reported as noise.
    best = 1 + int(np.argmax([filtered[labels == i].sum() for i in range(1, n)]))
    blob = labels == best
    if blob.sum() < settings.min_pixels:
        return None
    # A marker cut by the image border has a biased centre: not measured.
    x, y, w, h = stats[best, :4]
    edge = k + 1
    height, width = count.shape
    if x < edge or y < edge or x + w > width - edge or y + h > height - edge:
        return None
    # Sub-pixel centre: the silhouette (mean difference, saturated) around the blob, whose
    # edge pixels count in proportion to their coverage.
    rim = cv2.dilate(blob.astype(np.uint8), np.ones((2 * k + 1, 2 * k + 1), np.uint8)).astype(bool)
    mean_difference = weight / (len(stack) - 1)
    coverage = np.clip(mean_difference / settings.saturation_grey, 0.0, 1.0)
    w = np.where(rim & (count > 0), coverage, 0.0)
    v_idx, u_idx = np.nonzero(w)
    total = w[v_idx, u_idx].sum()
    u = float((u_idx * w[v_idx, u_idx]).sum() / total)
    v = float((v_idx * w[v_idx, u_idx]).sum() / total)
    return MarkerDetection(u, v, int(blob.sum()), peak)


def triangulate(stereo: StereoCamera, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
    """(N, 3) points in the left camera frame from matching pixels (N, 2) of a calibrated pair."""
    uv_left = np.asarray(uv_left, float).reshape(-1, 1, 2)
    uv_right = np.asarray(uv_right, float).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    xl = cv2.undistortPointsIter(
        uv_left, stereo.left.K, stereo.left.distortion, None, None, criteria
    )
    xr = cv2.undistortPointsIter(
        uv_right, stereo.right.K, stereo.right.distortion, None, None, criteria
    )
    P_left = np.hstack([np.eye(3), np.zeros((3, 1))])
    P_right = np.hstack([stereo.R, stereo.T.reshape(3, 1)])
    X = cv2.triangulatePoints(P_left, P_right, xl.reshape(-1, 2).T, xr.reshape(-1, 2).T)
    return (X[:3] / X[3]).T


def fit_rigid(p_A: np.ndarray, p_B: np.ndarray) -> np.ndarray:
    """X_AB minimising sum |p_A - X_AB p_B|^2 (Kabsch/Umeyama without scale), points (N, 3)."""
    p_A, p_B = np.asarray(p_A, float), np.asarray(p_B, float)
    if len(p_A) < 3 or len(p_A) != len(p_B):
        raise ScannerError(f"a rigid fit needs at least 3 point pairs, got {len(p_A)}")
    ca, cb = p_A.mean(axis=0), p_B.mean(axis=0)
    H = (p_B - cb).T @ (p_A - ca)
    U, S, Vt = np.linalg.svd(H)
    if S[1] < 1e-9 * max(S[0], 1e-30):
        raise ScannerError("a rigid fit needs points that are not all on one line")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return make_pose(R, ca - R @ cb)


@dataclass(frozen=True, eq=False)
class RigidFit:
    """X_AB with the indices kept and dropped, and every point's residual (m) under X_AB."""

    X_AB: np.ndarray
    inliers: np.ndarray
    outliers: np.ndarray
    residuals_m: np.ndarray

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_m[self.inliers] ** 2)))


def fit_rigid_robust(
    p_A: np.ndarray, p_B: np.ndarray, max_residual_m: float, min_points: int = 4
) -> RigidFit:
    """KTH's iterative rejection: refit without the farthest point while it exceeds the limit."""
    p_A, p_B = np.asarray(p_A, float), np.asarray(p_B, float)
    keep = np.arange(len(p_A))
    while True:
        X_AB = fit_rigid(p_A[keep], p_B[keep])
        residuals = np.linalg.norm(p_A - transform_points(X_AB, p_B), axis=1)
        worst = keep[int(np.argmax(residuals[keep]))]
        if residuals[worst] <= max_residual_m or len(keep) <= min_points:
            break
        keep = keep[keep != worst]
    dropped = np.setdiff1d(np.arange(len(p_A)), keep)
    return RigidFit(X_AB, keep, dropped, residuals)


@dataclass(frozen=True)
class HeldOutErrors:
    """Mean and std (m) of |x|, |y|, |z| and distance errors in the base frame (KTH Table 1)."""

    count: int
    mean_abs_xyz_m: tuple[float, float, float]
    std_abs_xyz_m: tuple[float, float, float]
    mean_distance_m: float
    std_distance_m: float
    max_distance_m: float


def held_out_errors(p_W_reported: np.ndarray, p_W_measured: np.ndarray) -> HeldOutErrors:
    d = np.asarray(p_W_measured, float) - np.asarray(p_W_reported, float)
    if len(d) == 0:
        raise ScannerError("no held-out point was measured")
    a = np.abs(d)
    dist = np.linalg.norm(d, axis=1)
    return HeldOutErrors(
        len(d),
        tuple(float(x) for x in a.mean(axis=0)),
        tuple(float(x) for x in a.std(axis=0)),
        float(dist.mean()),
        float(dist.std()),
        float(dist.max()),
    )


def grid_points(center_m: Sequence[float], size_m: Sequence[float], spacing_m: float) -> np.ndarray:
    """(N, 3) points of a regular grid filling the box (centre, full size) at the spacing."""
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise ScannerError(f"grid spacing must be a positive length, got {spacing_m}")
    axes = []
    for c, s in zip(center_m, size_m):
        n = int(math.floor(s / spacing_m + 1e-9)) + 1
        axes.append(c + (np.arange(n) - (n - 1) / 2) * spacing_m)
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([x.ravel() for x in g], axis=1)

"""How well two views' poses agree with their images, and a refinement when they do not.

A stereo pair from two arm poses is only as good as the relative pose X_CiCj that the arm and
the hand-eye calibration give: SGBM searches along rectified rows, so a point whose match lies
a pixel above or below its row is matched wrongly or not at all. The check is independent of
the stereo matcher: SIFT features matched between the two images (Lowe's ratio test, then
RANSAC on the essential matrix to drop wrong matches without trusting the poses), and the
distance of each match to the epipolar line that the given poses predict (symmetric: the mean
of both images' distances; what a rectified pair shows as |v_left - v_right|).

The refinement changes the relative ROTATION and the DIRECTION of the baseline (five degrees
of freedom, all that two images can tell) and keeps the baseline's length: the metric scale
comes from the arm, not from the images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose, rotvec_to_matrix, skew
from reconstruction.stereo.camera_model import PinholeCamera
from reconstruction.stereo.matching import grey_image


@dataclass(frozen=True)
class EpipolarConfig:
    """Feature matching and the limit above which a pair's relative pose is refined."""

    # Lowe's ratio test (SIFT paper, 2004: 0.8 drops 90 % of false matches); stricter here,
    # since RANSAC follows and a few hundred matches are plenty for five parameters.
    ratio_test: float = positive(0.75, at_most=1.0)
    max_features: int = integer(4000)
    # RANSAC's inlier distance to the epipolar line of the estimated essential matrix (px).
    ransac_threshold_px: float = positive(1.0)
    # Refine the relative pose when the median epipolar error is above this (px). Measured on
    # DTU's calibrated pairs: 0.2-0.3 px at 400x300, 0.35-0.55 px at 1600x1200; a relative
    # rotation off by 0.3 deg gives 2-4 px at 400x300.
    max_error_px: float = positive(1.0)
    # Prior of the refinement: how far (m) the arm may have put the other camera off the given
    # baseline direction (perpendicular to it). Without it, the few matches of a shallow scene
    # trade rotation for baseline direction: on 4x downscaled DTU pairs (50-100 matches) the
    # free fit moved the pose by up to 3 deg at the same epipolar error.
    baseline_sigma_m: float = positive(0.001)
    # And how far (rad) its relative rotation may be off. The rotation about the axis normal
    # to the baseline and the viewing direction (the pair's convergence) moves points along
    # their epipolar lines: the matches hardly constrain it, and a free fit let it wander by
    # 1 deg on the same pairs. The prior keeps the given value where the images say nothing.
    rotation_sigma_rad: float = positive(0.005)
    # Fewer inlier matches than this: no verdict (textureless or non-overlapping views).
    min_matches: int = integer(30, minimum=8)

    def __post_init__(self) -> None:
        check_fields("two_view.epipolar", self)


@dataclass(frozen=True)
class EpipolarError:
    """Symmetric distance of matched features to their epipolar lines (px): median and 90th
    percentile over `matches` RANSAC-inlier matches."""

    median_px: float
    p90_px: float
    matches: int


@dataclass(frozen=True, eq=False)
class FeatureMatches:
    """Matched features, undistorted, in pixels of each camera's pinhole K: (N, 2) each."""

    px_i: np.ndarray
    px_j: np.ndarray

    def __len__(self) -> int:
        return len(self.px_i)


@dataclass(frozen=True, eq=False)
class PoseRefinement:
    """X_CiCj (4x4) after the check: refined (True) or as given, with the errors before and
    after (equal when not refined)."""

    X_CiCj: np.ndarray
    before: EpipolarError
    after: EpipolarError
    refined: bool


def _undistorted_px(camera: PinholeCamera, px: np.ndarray) -> np.ndarray:
    if not np.any(camera.distortion):
        return px
    out = cv2.undistortPoints(px.reshape(-1, 1, 2), camera.K, camera.distortion, P=camera.K)
    return out.reshape(-1, 2)


def _normalised(camera: PinholeCamera, px: np.ndarray) -> np.ndarray:
    return (px - camera.K[:2, 2]) @ np.linalg.inv(camera.K[:2, :2]).T


def match_features(
    image_i: np.ndarray,
    image_j: np.ndarray,
    cam_i: PinholeCamera,
    cam_j: PinholeCamera,
    config: EpipolarConfig,
) -> FeatureMatches:
    """SIFT matches that pass the ratio test and RANSAC on the essential matrix (which uses
    the intrinsics only, never the poses under test); undistorted pixels."""
    sift = cv2.SIFT_create(nfeatures=config.max_features)
    keys_i, desc_i = sift.detectAndCompute(grey_image(image_i, "view i"), None)
    keys_j, desc_j = sift.detectAndCompute(grey_image(image_j, "view j"), None)
    empty = FeatureMatches(np.zeros((0, 2)), np.zeros((0, 2)))
    if desc_i is None or desc_j is None or len(keys_i) < 2 or len(keys_j) < 2:
        return empty
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_i, desc_j, k=2)
    good = [
        p[0] for p in pairs if len(p) == 2 and p[0].distance < config.ratio_test * p[1].distance
    ]
    if len(good) < 8:
        return empty
    px_i = _undistorted_px(cam_i, np.array([keys_i[m.queryIdx].pt for m in good], np.float64))
    px_j = _undistorted_px(cam_j, np.array([keys_j[m.trainIdx].pt for m in good], np.float64))
    # Normalised coordinates let two different intrinsics share one essential matrix.
    focal_px = 0.5 * (cam_i.K[0, 0] + cam_j.K[0, 0])
    _, inliers = cv2.findEssentialMat(
        _normalised(cam_i, px_i),
        _normalised(cam_j, px_j),
        np.eye(3),
        method=cv2.RANSAC,
        prob=0.999,
        threshold=config.ransac_threshold_px / focal_px,
    )
    if inliers is None:
        return empty
    keep = inliers.ravel().astype(bool)
    return FeatureMatches(px_i[keep], px_j[keep])


def fundamental_matrix(cam_i: PinholeCamera, cam_j: PinholeCamera, X_CiCj: np.ndarray):
    """F (3x3) with x_j^T F x_i = 0 for undistorted pixels of a point seen by both cameras."""
    X_CjCi = invert(X_CiCj)
    E = skew(X_CjCi[:3, 3])[0] @ X_CjCi[:3, :3]
    return np.linalg.inv(cam_j.K).T @ E @ np.linalg.inv(cam_i.K)


def epipolar_distances_px(matches: FeatureMatches, F: np.ndarray) -> np.ndarray:
    """(N,) signed symmetric distances (px): the mean of each image's point-to-line distance."""
    x_i = np.column_stack([matches.px_i, np.ones(len(matches))])
    x_j = np.column_stack([matches.px_j, np.ones(len(matches))])
    lines_j = x_i @ F.T  # F x_i: lines in image j
    lines_i = x_j @ F  # F^T x_j: lines in image i
    algebraic = np.sum(x_j * lines_j, axis=1)
    return (
        0.5
        * algebraic
        * (1 / np.linalg.norm(lines_j[:, :2], axis=1) + 1 / np.linalg.norm(lines_i[:, :2], axis=1))
    )


def error_of(
    matches: FeatureMatches, cam_i: PinholeCamera, cam_j: PinholeCamera, X_CiCj: np.ndarray
) -> EpipolarError:
    """The EpipolarError of given matches under the relative pose X_CiCj."""
    if len(matches) == 0:
        return EpipolarError(math.nan, math.nan, 0)
    d = np.abs(epipolar_distances_px(matches, fundamental_matrix(cam_i, cam_j, X_CiCj)))
    return EpipolarError(float(np.median(d)), float(np.percentile(d, 90)), len(matches))


def epipolar_error(
    image_i: np.ndarray,
    image_j: np.ndarray,
    cam_i: PinholeCamera,
    cam_j: PinholeCamera,
    X_CiCj: np.ndarray,
    config: EpipolarConfig | None = None,
) -> EpipolarError:
    """How far the images' matched features lie from the epipolar lines of the relative pose
    X_CiCj (pose of camera j in camera i, metres)."""
    config = config or EpipolarConfig()
    return error_of(match_features(image_i, image_j, cam_i, cam_j, config), cam_i, cam_j, X_CiCj)


def _tangent_basis(direction: np.ndarray) -> np.ndarray:
    """(3, 2): two unit vectors perpendicular to `direction` and to each other."""
    u = direction / np.linalg.norm(direction)
    helper = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(u, e1)])


def refined_pose(
    matches: FeatureMatches,
    cam_i: PinholeCamera,
    cam_j: PinholeCamera,
    X_CiCj: np.ndarray,
    robust_scale_px: float,
    baseline_sigma_m: float,
    rotation_sigma_rad: float,
) -> np.ndarray:
    """X_CiCj whose rotation and baseline direction minimise the matches' epipolar distances
    (in units of robust_scale_px, soft-L1 beyond one) plus the priors that the other camera
    moves off the given baseline direction by about baseline_sigma_m and turns by about
    rotation_sigma_rad; the baseline length stays that of the given pose."""
    R0, p0 = X_CiCj[:3, :3], X_CiCj[:3, 3]
    length_m = float(np.linalg.norm(p0))
    basis = _tangent_basis(p0)

    def pose(x: np.ndarray) -> np.ndarray:
        p = p0 / length_m + basis @ x[3:]
        return make_pose(rotvec_to_matrix(x[:3]) @ R0, length_m * p / np.linalg.norm(p))

    def residuals(x: np.ndarray) -> np.ndarray:
        px = epipolar_distances_px(matches, fundamental_matrix(cam_i, cam_j, pose(x)))
        # soft-L1 would also flatten the prior; applied by hand to the matches only.
        r = px / robust_scale_px
        robust = np.sign(r) * np.sqrt(2 * (np.sqrt(1 + r * r) - 1))
        prior = np.concatenate([x[:3] / rotation_sigma_rad, x[3:] * length_m / baseline_sigma_m])
        return np.concatenate([robust, prior])

    result = least_squares(residuals, np.zeros(5))
    return pose(result.x)


def refine_relative_pose(
    image_i: np.ndarray,
    image_j: np.ndarray,
    cam_i: PinholeCamera,
    cam_j: PinholeCamera,
    X_CiCj: np.ndarray,
    config: EpipolarConfig | None = None,
) -> PoseRefinement:
    """The relative pose checked against the images and, when its median epipolar error is
    above config.max_error_px, refined (rotation and baseline direction; `refined_pose`).
    Too few matches for a verdict: a ScannerError naming the limit."""
    config = config or EpipolarConfig()
    matches = match_features(image_i, image_j, cam_i, cam_j, config)
    if len(matches) < config.min_matches:
        raise ScannerError(
            f"view pair: {len(matches)} feature matches, two_view.epipolar.min_matches is "
            f"{config.min_matches}: the views share too little texture to check their poses"
        )
    return checked_pose(matches, cam_i, cam_j, X_CiCj, config)


def checked_pose(
    matches: FeatureMatches,
    cam_i: PinholeCamera,
    cam_j: PinholeCamera,
    X_CiCj: np.ndarray,
    config: EpipolarConfig,
) -> PoseRefinement:
    """`refine_relative_pose` on matches already made; with fewer than config.min_matches the
    pose stays as given (no verdict either way)."""
    before = error_of(matches, cam_i, cam_j, X_CiCj)
    if len(matches) < config.min_matches or before.median_px <= config.max_error_px:
        return PoseRefinement(X_CiCj, before, before, False)
    X_refined = refined_pose(
        matches,
        cam_i,
        cam_j,
        X_CiCj,
        config.ransac_threshold_px,
        config.baseline_sigma_m,
        config.rotation_sigma_rad,
    )
    return PoseRefinement(X_refined, before, error_of(matches, cam_i, cam_j, X_refined), True)

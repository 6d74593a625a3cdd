"""A depth camera's scale error found with the calibration board: the board's plane measured in
the depth image against the same plane from its pose in the colour image.

A depth camera's reported depth can be off by a factor (a depth-scale error: a known failure of
stereo-IR devices whose imagers' calibration drifted). The colour camera's board pose (PnP on
the corners, metric through the printed board's size) gives the plane n . p = d in the depth
frame D through the device's extrinsics; a depth pixel on the board, lifted at the reported
depth z along its ray r, lies on it when c z (n . r) = d, so each pixel votes c = d / (z n . r).
The median over every board pixel of every pose is robust to the board's edges and holes.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.calibration.boards import BoardSpec, Detection
from reconstruction.calibration.observations import board_pose
from reconstruction.common.errors import ScannerError
from reconstruction.depth.camera_model import RgbdCamera
from reconstruction.depth.cloud import depth_points_D

# Pixels this far inside the board's outline only (the depth edge blurs and flies).
INSET_FRACTION = 0.1
# Fewer board pixels than this in a pose: that pose does not vote.
MIN_PIXELS_PER_POSE = 200


@dataclass(frozen=True)
class DepthScaleFit:
    """correction: true depth = reported depth x correction (median over all votes); spread:
    half the 16-84 % range of the per-pose medians (a 1-sigma of one pose); poses: how many
    voted; pixels: how many board pixels in all."""

    correction: float
    spread: float
    poses: int
    pixels: int


def board_pixels_D(
    board: BoardSpec, X_DB: np.ndarray, camera: RgbdCamera
) -> tuple[np.ndarray, np.ndarray]:
    """The depth pixels (N, 2) inside the board's inset outline, and the board plane (n, d) in D
    (n . p = d for points p of the board, n towards the camera's far side)."""
    p_B = board.object_points()
    lo, hi = p_B[:, :2].min(axis=0), p_B[:, :2].max(axis=0)
    inset = INSET_FRACTION * (hi - lo)
    corners_B = np.array(
        [
            [lo[0] + inset[0], lo[1] + inset[1], 0],
            [hi[0] - inset[0], lo[1] + inset[1], 0],
            [hi[0] - inset[0], hi[1] - inset[1], 0],
            [lo[0] + inset[0], hi[1] - inset[1], 0],
        ]
    )
    p_D = corners_B @ X_DB[:3, :3].T + X_DB[:3, 3]
    cam = camera.depth
    uv, _ = cv2.projectPoints(
        p_D.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.distortion
    )
    mask = np.zeros((cam.height, cam.width), np.uint8)
    cv2.fillConvexPoly(mask, np.round(uv.reshape(-1, 2)).astype(np.int32), 1)
    v, u = np.nonzero(mask)
    n = X_DB[:3, 2]
    return np.column_stack([u, v]).astype(np.float64), np.array([*n, n @ X_DB[:3, 3]])


def depth_scale_fit(
    board: BoardSpec,
    detections: list[Detection],
    depths: list[np.ndarray],
    color_camera,
    camera: RgbdCamera,
) -> DepthScaleFit:
    """The depth-scale correction from poses with the board found in the colour image (its
    detection and that pose's depth counts), with the calibrated colour camera."""
    X_DC = np.linalg.inv(camera.X_CD)
    medians, pixels = [], 0
    for detection, counts in zip(detections, depths):
        X_DB = X_DC @ board_pose(board, detection, color_camera)
        uv, plane = board_pixels_D(board, X_DB, camera)
        z = counts[uv[:, 1].astype(int), uv[:, 0].astype(int)] * camera.depth_scale_m
        keep = z > 0
        if keep.sum() < MIN_PIXELS_PER_POSE:
            continue
        rays = depth_points_D(camera, np.ones(int(keep.sum())), uv[keep])
        votes = plane[3] / (z[keep] * (rays @ plane[:3]))
        medians.append(float(np.median(votes)))
        pixels += int(keep.sum())
    if not medians:
        raise ScannerError(
            "depth scale: no pose shows enough of the board in the depth image "
            f"(at least {MIN_PIXELS_PER_POSE} pixels with depth inside its outline)"
        )
    p16, p84 = np.percentile(medians, [16, 84])
    return DepthScaleFit(float(np.median(medians)), float((p84 - p16) / 2), len(medians), pixels)

"""Board patterns seen in perspective, with the exact pixel of every board point, for the
detection tests."""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.calibration.boards import BoardSpec, board_image


def warped_board(spec: BoardSpec, px_per_spacing: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """The pattern image warped by a fixed homography, and the pixel (OpenCV centres, (N, 2))
    of each of the board's points in `spec.object_points()` order."""
    pattern = board_image(spec, px_per_spacing=px_per_spacing)
    h, w = pattern.image.shape
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = np.float32([[60, 40], [60 + 0.95 * w, 70], [40 + w, 30 + 0.9 * h], [30, 20 + h]])
    H = cv2.getPerspectiveTransform(src, dst)
    size = (int(w * 1.2) + 80, int(h * 1.2) + 80)
    # Pixel-edge coordinates (pattern) -> OpenCV pixel-centre coordinates: -0.5 on both sides.
    shift = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])
    unshift = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    image = cv2.warpPerspective(
        pattern.image, shift @ H @ unshift, size, flags=cv2.INTER_AREA, borderValue=255
    )
    edges = pattern.origin_px + spec.object_points()[:, :2] * pattern.px_per_m
    return image, cv2.perspectiveTransform(edges[None].astype(np.float64), H)[0] - 0.5

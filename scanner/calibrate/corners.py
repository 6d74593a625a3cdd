"""Per-image corner pictures: the board corners each image showed (green circles) and where the
final calibration puts them (red crosses), one PNG per image in results/corners/, worst first.

A user sees at a glance what a number cannot say: a corner found on the wrong square, a blurred
or partly hidden board, a pose whose robot reading is off (every cross shifted the same way).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.refine import reprojection_residuals, sensor_points

# Pictures wider than this are downscaled (a 1280 px picture shows a 0.3 px offset as a visible
# gap between circle and cross when zoomed, and keeps a 40-image folder near 20 MB).
MAX_WIDTH_PX = 1280
# Beyond this many images only the worst are drawn (they are the ones worth a look).
MAX_PICTURES = 200
DETECTED_BGR = (0, 200, 0)
REPROJECTED_BGR = (0, 0, 255)
FONT = cv2.FONT_HERSHEY_SIMPLEX

# (name, side) -> the image, loaded only when its picture is drawn.
ImageLoader = Callable[[str, str], np.ndarray]


@dataclass(frozen=True, eq=False)
class CornerPicture:
    """One image's detected and reprojected corners (N, 2) px and their RMS distance (px)."""

    name: str
    side: str  # "left" or "right"
    detected_px: np.ndarray
    reprojected_px: np.ndarray
    rms_px: float
    file_name: str = ""


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text)


def rank_pictures(board: BoardSpec, solution) -> list[CornerPicture]:
    """Every image with a board of every used or outlier pose, worst RMS first, named
    NN_[worst_]<pose>_<side>_rms<R>px.png (at most MAX_PICTURES)."""
    he = solution.hand_eye
    cameras = solution.calibration.stereo or solution.calibration.camera
    out = []
    for o in solution.observations:
        if o.left is None or o.name not in he.X_CB:
            continue
        sensors = sensor_points(board, [o], cameras)
        residuals = reprojection_residuals(sensors, o.X_WF[None], he.X_FC, he.X_WB)
        sides = ["left", "right"] if o.right is not None else ["left"]
        for side, s, r in zip(sides, sensors, residuals):
            rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
            out.append(CornerPicture(o.name, side, s.pixels, s.pixels - r, rms))
    out.sort(key=lambda p: -p.rms_px)
    out = out[:MAX_PICTURES]
    width = max(2, len(str(len(out))))
    named = []
    for k, p in enumerate(out, 1):
        worst = "worst_" if k == 1 else ""
        file_name = f"{k:0{width}d}_{worst}{_safe(p.name)}_{p.side}_rms{p.rms_px:.2f}px.png"
        named.append(
            CornerPicture(p.name, p.side, p.detected_px, p.reprojected_px, p.rms_px, file_name)
        )
    return named


def draw_picture(image: np.ndarray, picture: CornerPicture) -> np.ndarray:
    """The image in grey (so the colours stand out), downscaled to MAX_WIDTH_PX, with the
    corners and a legend line."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    scale = min(1.0, MAX_WIDTH_PX / grey.shape[1])
    if scale < 1.0:
        size = (round(grey.shape[1] * scale), round(grey.shape[0] * scale))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    canvas = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    radius = max(3, round(6 * scale))
    for u, v in picture.detected_px * scale:
        cv2.circle(canvas, (round(u), round(v)), radius, DETECTED_BGR, 1, cv2.LINE_AA)
    for u, v in picture.reprojected_px * scale:
        cv2.drawMarker(
            canvas,
            (round(u), round(v)),
            REPROJECTED_BGR,
            cv2.MARKER_CROSS,
            2 * radius,
            1,
            cv2.LINE_AA,
        )
    cv2.rectangle(canvas, (0, 0), (canvas.shape[1], 28), (255, 255, 255), -1)
    x = 8
    for mark, text in (
        (None, f"{picture.name} {picture.side}: RMS {picture.rms_px:.3f} px"),
        (DETECTED_BGR, "detected"),
        (REPROJECTED_BGR, "reprojected by the calibration"),
    ):
        if mark == DETECTED_BGR:
            cv2.circle(canvas, (x + 6, 14), 5, mark, 1, cv2.LINE_AA)
            x += 16
        elif mark is not None:
            cv2.drawMarker(canvas, (x + 6, 14), mark, cv2.MARKER_CROSS, 12, 1, cv2.LINE_AA)
            x += 16
        cv2.putText(canvas, text, (x, 20), FONT, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
        x += cv2.getTextSize(text, FONT, 0.55, 1)[0][0] + 20
    return canvas


def write_pictures(folder: Path, pictures: list[CornerPicture], load: ImageLoader) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for p in pictures:
        canvas = draw_picture(load(p.name, p.side), p)
        if not cv2.imwrite(str(folder / p.file_name), canvas):
            raise OSError(f"{folder / p.file_name}: could not be written")


def rms_of(pictures: list[CornerPicture]) -> float:
    """The RMS over every picture's corners (equals the hand-eye RMS over the same poses)."""
    sq = [np.sum((p.detected_px - p.reprojected_px) ** 2, axis=1) for p in pictures]
    return math.sqrt(float(np.mean(np.concatenate(sq)))) if sq else math.nan

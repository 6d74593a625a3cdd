"""The recorded data of an eye-to-hand calibration: per marker point, the blink frames of both
static cameras and the reported flange pose, so `scanner calibrate --eye-to-hand --offline DIR`
solves again from them.

Layout of DIR:
    eye_to_hand_points.yaml     static camera, marker p_FM (m), frames, window (px), points
    points/NNNN/left.png        the point's frames of the left camera, stacked top to bottom
    points/NNNN/right.png       the same for the right camera
    points/NNNN/pose.txt        X_WF as reported, 4x4 row by row in metres (--offline's matrix)
    points/NNNN/window.yaml     each window's top-left pixel in the full image

Frames are stored as a window around the marker (a camera's region of interest, as fast
machine-vision cameras read out for a blinking LED): 20 full VGA frames of 136 points in both
cameras would be 1.6 GB, the windows are ~1 % of that. The live run detects the marker in the
windows too, so a re-solve repeats it exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from reconstruction.calibration.pose_files import PoseFormat, read_pose_file
from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml
from reconstruction.stereo.camera_model import (
    StereoCamera,
    stereo_camera_from_dict,
    stereo_camera_to_dict,
)
from scanner.scan_dir.captures import atomic_write_text

MANIFEST = "eye_to_hand_points.yaml"
SCHEMA = "scanner.eye_to_hand_points/1"
POINTS = "points"
# Half the window (px): the marker is a few pixels across; the detector's box filter and border
# test need a margin of a few more.
WINDOW_HALF_PX = 32


@dataclass(frozen=True, eq=False)
class MarkerRecord:
    """One marker point: which set ("grid" or "held_out"), the reported X_WF, the frames (F, h, w)
    of each camera's window and the window's top-left pixel (x, y) in the full image."""

    index: int
    kind: str
    X_WF: np.ndarray
    left: np.ndarray
    right: np.ndarray
    left_origin_px: tuple[int, int]
    right_origin_px: tuple[int, int]


def window(frames: list[np.ndarray], u: float, v: float) -> tuple[np.ndarray, tuple[int, int]]:
    """The frames cut to the window around (u, v), clipped to the image, and its origin."""
    h, w = frames[0].shape
    x0 = int(np.clip(round(u) - WINDOW_HALF_PX, 0, max(w - 2 * WINDOW_HALF_PX, 0)))
    y0 = int(np.clip(round(v) - WINDOW_HALF_PX, 0, max(h - 2 * WINDOW_HALF_PX, 0)))
    size = 2 * WINDOW_HALF_PX
    return np.stack([f[y0 : y0 + size, x0 : x0 + size] for f in frames]), (x0, y0)


def write_manifest(
    root: Path, stereo: StereoCamera, p_FM: np.ndarray, frames: int, truth: dict | None
) -> None:
    root.mkdir(parents=True, exist_ok=True)
    manifest = {
        "schema": SCHEMA,
        "static_camera": stereo_camera_to_dict(stereo),
        "marker_p_FM": [float(v) for v in p_FM],
        "frames": int(frames),
        "window_px": 2 * WINDOW_HALF_PX,
    }
    if truth:
        manifest["truth"] = truth  # simulation only: for evaluation
    atomic_write_text(root / MANIFEST, yaml.safe_dump(manifest, sort_keys=False))


def write_point(root: Path, record: MarkerRecord) -> None:
    folder = root / POINTS / f"{record.index:04d}"
    folder.mkdir(parents=True, exist_ok=True)
    for side in ("left", "right"):
        stack = getattr(record, side)
        if not cv2.imwrite(str(folder / f"{side}.png"), stack.reshape(-1, stack.shape[2])):
            raise OSError(f"{folder / side}.png: could not be written")
    atomic_write_text(
        folder / "pose.txt",
        "\n".join(" ".join(repr(float(v)) for v in row) for row in record.X_WF) + "\n",
    )
    atomic_write_text(
        folder / "window.yaml",
        yaml.safe_dump(
            {
                "kind": record.kind,
                "left_origin_px": list(record.left_origin_px),
                "right_origin_px": list(record.right_origin_px),
            },
            sort_keys=False,
        ),
    )


def is_eye_to_hand_data(root: Path) -> bool:
    return (Path(root) / MANIFEST).is_file()


def read_manifest(root: Path) -> tuple[dict, StereoCamera, np.ndarray]:
    path = Path(root) / MANIFEST
    if not path.is_file():
        raise ScannerError(
            f"{root}: no {MANIFEST}; --eye-to-hand --offline reads a folder that "
            "`scanner calibrate --eye-to-hand` wrote"
        )
    d = read_yaml(path, "eye-to-hand points")
    if not isinstance(d, dict) or d.get("schema") != SCHEMA:
        raise ScannerError(f"{path}: schema must be {SCHEMA}")
    try:
        stereo = stereo_camera_from_dict(d["static_camera"], f"{path}:static_camera")
        p_FM = np.array(d["marker_p_FM"], float).reshape(3)
        frames = int(d["frames"])
    except (KeyError, TypeError, ValueError) as e:
        raise ScannerError(f"{path}: missing or malformed field ({e})") from None
    if frames < 2:
        raise ScannerError(f"{path}: frames must be at least 2")
    return d, stereo, p_FM


def read_points(root: Path, frames: int) -> list[MarkerRecord]:
    folders = sorted((Path(root) / POINTS).glob("[0-9][0-9][0-9][0-9]"))
    if not folders:
        raise ScannerError(f"{Path(root) / POINTS}: no marker points recorded")
    records = []
    for folder in folders:
        meta = read_yaml(folder / "window.yaml", "marker window")
        stacks = []
        for side in ("left", "right"):
            image = cv2.imread(str(folder / f"{side}.png"), cv2.IMREAD_GRAYSCALE)
            if image is None or image.shape[0] % frames:
                raise ScannerError(
                    f"{folder / side}.png: missing, unreadable, or not {frames} stacked frames"
                )
            stacks.append(image.reshape(frames, -1, image.shape[1]))
        try:
            kind = str(meta["kind"])
            origins = [tuple(int(v) for v in meta[f"{s}_origin_px"]) for s in ("left", "right")]
        except (KeyError, TypeError, ValueError) as e:
            raise ScannerError(
                f"{folder / 'window.yaml'}: missing or malformed field ({e})"
            ) from None
        if kind not in ("grid", "held_out"):
            raise ScannerError(f"{folder / 'window.yaml'}: kind must be grid or held_out")
        X_WF = read_pose_file(folder / "pose.txt", PoseFormat(layout="matrix", length_unit="m"))
        records.append(MarkerRecord(int(folder.name), kind, X_WF, *stacks, *origins))
    return records

"""IDR / NeuS recordings: `cameras_sphere.npz` (or IDR's `cameras.npz`) beside `image/` or
`images/` and an optional `mask/` (DTU MVS as published with IDR and NeuS).

For view i the file holds world_mat_i, whose top three rows are the projection P_i = K [R_i | t_i]
(x_pixel ~ P_i X_world, pixel centres at integer coordinates as in OpenCV), and scale_mat_i,
which maps the unit sphere around the object into the world (world = scale_mat @ sphere). The
world unit is the source's: DTU's calibration is in millimetres, hence the default 0.001 m per
unit. P is split as IDR's own loader does it (cv2.decomposeProjectionMatrix: K, R_CW and the
camera centre), and the split is checked by projecting the scene centre both ways.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose
from reconstruction.recordings.recording import (
    IMAGE_SUFFIXES,
    RecordedView,
    Recording,
    image_size,
    masks_in_order,
    sorted_files,
)
from reconstruction.stereo.camera_model import PinholeCamera

FORMAT = "idr"
CAMERA_FILES = ("cameras_sphere.npz", "cameras.npz")
IMAGE_FOLDERS = ("image", "images")
MASK_FOLDER = "mask"
# DTU MVS (the data IDR and NeuS publish in this form) is calibrated in millimetres.
DEFAULT_METRES_PER_UNIT = 0.001
# How far a pixel may move when K's skew is dropped (at the image's top or bottom edge), and how
# far the split P may project the scene centre from where P itself does.
MAX_SKEW_SHIFT_PX = 0.05
MAX_SPLIT_ERROR_PX = 0.1


def camera_file(folder: Path) -> Path | None:
    """The camera file of an IDR folder, or None when it is not one."""
    for name in CAMERA_FILES:
        if (Path(folder) / name).is_file():
            return Path(folder) / name
    return None


def split_projection(
    P: np.ndarray, where: str, width: int, height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K (3x3, K[2,2] = 1, no skew), R_CW (3x3 rotation) and the camera centre p_WC (3, in
    the source's unit) of a 3x4 projection P = s K [R_CW | -R_CW p_WC]."""
    if P.shape != (3, 4) or not np.all(np.isfinite(P)):
        raise ScannerError(f"{where}: expected a finite 3x4 projection, got {P.tolist()}")
    M = P[:, :3]
    if abs(np.linalg.det(M)) <= 1e-12 * np.abs(M).max() ** 3:
        raise ScannerError(f"{where}: the projection's 3x3 part is singular (not a camera)")
    K, R_CW, c_h = cv2.decomposeProjectionMatrix(P.astype(np.float64))[:3]
    # RQ leaves the signs of K's diagonal free: make them positive, moving the signs into R
    # (K D D R with D = D^-1), and a remaining reflection into the projection's overall sign,
    # which homogeneous pixels do not see.
    D = np.diag(np.sign(np.diag(K)))
    K, R_CW = K @ D, D @ R_CW
    if np.linalg.det(R_CW) < 0:
        R_CW = -R_CW
    K = K / K[2, 2]
    if abs(c_h[3, 0]) < 1e-12 * np.abs(c_h[:3, 0]).max():
        raise ScannerError(f"{where}: the camera centre lies at infinity (not a pinhole camera)")
    p_WC = c_h[:3, 0] / c_h[3, 0]
    # Skew moves a pixel at image row v by skew * (v - cy) / fy.
    skew_shift_px = abs(K[0, 1]) * max(K[1, 2], height - K[1, 2]) / K[1, 1]
    if skew_shift_px > MAX_SKEW_SHIFT_PX:
        raise ScannerError(
            f"{where}: K has skew {K[0, 1]:.4g} px (moves pixels by up to {skew_shift_px:.3g} px); "
            f"expected a camera without skew (at most {MAX_SKEW_SHIFT_PX} px)"
        )
    K[0, 1] = 0.0
    return K, R_CW, p_WC


def project(P: np.ndarray, p_W: np.ndarray) -> np.ndarray:
    x = P @ np.append(p_W, 1.0)
    return x[:2] / x[2]


def check_split(
    P: np.ndarray, K: np.ndarray, R_CW: np.ndarray, p_WC: np.ndarray, p_W: np.ndarray, where: str
) -> None:
    """The split must reproduce P: the point p_W (the scene centre) projects to the same pixel
    through P and through K, X_CW, and lies in front of the camera."""
    p_C = R_CW @ (p_W - p_WC)
    if p_C[2] <= 0:
        raise ScannerError(
            f"{where}: the scene centre (scale_mat) lies behind the camera (z = {p_C[2]:.4g}); "
            "expected world_mat to project the object into the image"
        )
    ours = (K @ p_C)[:2] / p_C[2]
    theirs = project(P, p_W)
    if np.linalg.norm(ours - theirs) > MAX_SPLIT_ERROR_PX:
        raise ScannerError(
            f"{where}: K, X_WC project the scene centre to {ours.round(2).tolist()} px, the "
            f"projection itself to {theirs.round(2).tolist()} px; expected P = K [R | t]"
        )


def _view_count(data, path: Path) -> int:
    indices = sorted(
        int(m.group(1)) for k in data.files if (m := re.fullmatch(r"world_mat_(\d+)", k))
    )
    if not indices:
        raise ScannerError(f"{path}: no world_mat_0, world_mat_1, ...; expected an IDR camera file")
    if indices != list(range(len(indices))):
        gaps = sorted(set(range(indices[-1] + 1)) - set(indices))
        raise ScannerError(
            f"{path}: world_mat_i for i = 0 .. {indices[-1]} expected, missing {gaps[:5]}"
        )
    return len(indices)


def _array(data, key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    try:
        a = np.asarray(data[key], dtype=float)
    except (ValueError, TypeError):
        raise ScannerError(f"{path}: {key} is not numeric") from None
    if a.shape not in (shape, (4, 4)):
        raise ScannerError(f"{path}: {key} has shape {a.shape}, expected {shape} or (4, 4)")
    return a


def image_folder(folder: Path) -> Path:
    for name in IMAGE_FOLDERS:
        if (Path(folder) / name).is_dir():
            return Path(folder) / name
    raise ScannerError(f"{folder}: no image/ or images/ folder beside the camera file")


def read_idr(
    folder: Path, metres_per_unit: float | None = None, masks: Path | None = None
) -> Recording:
    """The recording of an IDR / NeuS folder. metres_per_unit: the world's unit (None: the
    format's default, DTU's millimetres); masks: a folder of masks (None: `mask/` when there)."""
    folder = Path(folder).resolve()
    path = camera_file(folder)
    if path is None:
        raise ScannerError(f"{folder}: no {' or '.join(CAMERA_FILES)}; expected an IDR folder")
    unit_m = DEFAULT_METRES_PER_UNIT if metres_per_unit is None else float(metres_per_unit)
    try:
        data = np.load(path)
    except (OSError, ValueError) as e:
        raise ScannerError(f"{path}: not a readable .npz file ({e})") from None
    n = _view_count(data, path)
    images = sorted_files(image_folder(folder), IMAGE_SUFFIXES)
    if len(images) != n:
        raise ScannerError(
            f"{path}: {n} cameras (world_mat_i), but {len(images)} images in "
            f"{image_folder(folder)}; expected one image per camera, in the order of their names"
        )
    if masks is None and (folder / MASK_FOLDER).is_dir():
        masks = folder / MASK_FOLDER
    mask_paths = masks_in_order(masks, n, images) if masks is not None else [None] * n
    width, height = image_size(images[0])
    views = []
    for i in range(n):
        where = f"{path}: world_mat_{i}"
        P = _array(data, f"world_mat_{i}", (3, 4), path)[:3]
        key = f"scale_mat_{i}"
        scale_mat = _array(data, key, (4, 4), path) if key in data.files else np.eye(4)
        # Checked for every view against the first image's size; each image's own size is
        # checked against its camera with the rest of the recording.
        K, R_CW, p_WC = split_projection(P, where, width, height)
        check_split(P, K, R_CW, p_WC, scale_mat[:3, 3], where)
        views.append(
            RecordedView(
                index=i,
                image_path=images[i],
                camera=PinholeCamera(K, np.zeros(5), width, height),
                X_WC=make_pose(R_CW.T, p_WC * unit_m),
                mask_path=mask_paths[i],
            )
        )
    return Recording(tuple(views), FORMAT, folder, unit_m, camera_poses_given=True)

"""COLMAP recordings: a sparse model (text or binary) with its images, in COLMAP's project
layout: SOURCE/images/NAME and the model in SOURCE/sparse/0/, SOURCE/sparse/ or SOURCE/.

A COLMAP model has no unit: its scale is whatever the reconstruction chose. It is accepted only
with a stated metric scale, `metres_per_unit` or a known distance between two cameras' centres.

Pixel convention: COLMAP puts the centre of the top-left pixel at (0.5, 0.5) (COLMAP's camera
model documentation), OpenCV and this product at (0, 0); the principal point moves by half a
pixel on the way in (and back in the writer).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose
from reconstruction.recordings.colmap_model import (
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    model_files,
    read_model,
)
from reconstruction.recordings.recording import (
    IMAGE_SUFFIXES,
    RecordedView,
    Recording,
    masks_in_order,
    sorted_files,
)
from reconstruction.stereo.camera_model import PinholeCamera

FORMAT = "colmap"
MODEL_FOLDERS = ("sparse/0", "sparse", ".")
IMAGES_FOLDER = "images"
# COLMAP pixel (0.5, 0.5) is OpenCV pixel (0, 0).
COLMAP_PIXEL_OFFSET = 0.5


@dataclass(frozen=True)
class KnownDistance:
    """The distance between the camera centres of two images (file names as in the model)."""

    image_a: str
    image_b: str
    distance_m: float


def model_folder(source: Path) -> Path | None:
    for name in MODEL_FOLDERS:
        if model_files(Path(source) / name) is not None:
            return (Path(source) / name).resolve()
    return None


def pinhole_of(camera: ColmapCamera, where: str) -> PinholeCamera:
    """K and OpenCV distortion (k1, k2, p1, p2, k3) of the COLMAP models that map onto them;
    any other model is refused by name."""
    p = camera.params
    if camera.model == "SIMPLE_PINHOLE":
        (fx, cx, cy), fy, dist = p, p[0], [0.0] * 5
    elif camera.model == "PINHOLE":
        (fx, fy, cx, cy), dist = p, [0.0] * 5
    elif camera.model == "SIMPLE_RADIAL":
        (fx, cx, cy, _), fy, dist = p, p[0], [p[3], 0.0, 0.0, 0.0, 0.0]
    elif camera.model == "RADIAL":
        (fx, cx, cy, _, _), fy, dist = p, p[0], [p[3], p[4], 0.0, 0.0, 0.0]
    elif camera.model == "OPENCV":
        (fx, fy, cx, cy), dist = p[:4], [*p[4:8], 0.0]
    else:
        raise ScannerError(
            f"{where}: camera {camera.camera_id} uses the COLMAP model {camera.model}; expected "
            "PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL or OPENCV (undistort the images "
            "with COLMAP first)"
        )
    if not np.all(np.isfinite(p)) or fx <= 0 or fy <= 0:
        raise ScannerError(
            f"{where}: camera {camera.camera_id}: expected finite parameters and positive focal "
            f"lengths, got {p.tolist()}"
        )
    K = np.array(
        [[fx, 0, cx - COLMAP_PIXEL_OFFSET], [0, fy, cy - COLMAP_PIXEL_OFFSET], [0, 0, 1.0]]
    )
    return PinholeCamera(K, np.array(dist, float), camera.width, camera.height)


def colmap_camera_of(camera: PinholeCamera, camera_id: int) -> ColmapCamera:
    """The OPENCV-model camera of a pinhole camera with k3 = 0 (the writer's inverse)."""
    K, d = camera.K, camera.distortion
    if d[4] != 0:
        raise ValueError("COLMAP's OPENCV model has no k3")
    params = np.array(
        [
            K[0, 0],
            K[1, 1],
            K[0, 2] + COLMAP_PIXEL_OFFSET,
            K[1, 2] + COLMAP_PIXEL_OFFSET,
            *d[:4],
        ]
    )
    return ColmapCamera(camera_id, "OPENCV", camera.width, camera.height, params)


def X_CW_of(image: ColmapImage, where: str) -> np.ndarray:
    """X_CW (4x4, the model's unit) of an image; its quaternion must be finite and non-zero."""
    q, t = image.qvec, image.tvec
    norm = float(np.linalg.norm(q)) if np.all(np.isfinite(q)) else 0.0
    if norm < 1e-9 or not np.all(np.isfinite(t)):
        raise ScannerError(
            f"{where}: image {image.image_id} ({image.name}): expected a finite non-zero "
            f"quaternion and translation, got q {q.tolist()}, t {t.tolist()}"
        )
    R_CW = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()  # scipy: scalar last
    return make_pose(R_CW, t)


def image_of(X_CW: np.ndarray, image_id: int, camera_id: int, name: str) -> ColmapImage:
    """The image record of a pose X_CW (the writer's inverse of X_CW_of)."""
    x, y, z, w = Rotation.from_matrix(X_CW[:3, :3]).as_quat()
    return ColmapImage(image_id, np.array([w, x, y, z]), X_CW[:3, 3].copy(), camera_id, name)


def _scale(
    model: ColmapModel,
    X_WC: dict[str, np.ndarray],
    metres_per_unit: float | None,
    known: KnownDistance | None,
    where: str,
) -> float:
    if metres_per_unit is not None and known is not None:
        raise ScannerError("--scale and --known-distance: give one of them, not both")
    if metres_per_unit is not None:
        return float(metres_per_unit)
    if known is None:
        raise ScannerError(
            f"{where}: a COLMAP model has no unit; give its scale with --scale METRES_PER_UNIT "
            "or --known-distance IMAGE_A IMAGE_B METRES"
        )
    for name in (known.image_a, known.image_b):
        if name not in X_WC:
            raise ScannerError(
                f"--known-distance: no image named {name!r} in {where}; expected names such as "
                f"{', '.join(sorted(X_WC)[:3])}"
            )
    d_model = float(np.linalg.norm(X_WC[known.image_a][:3, 3] - X_WC[known.image_b][:3, 3]))
    if not d_model > 1e-12:
        raise ScannerError(
            f"--known-distance: {known.image_a} and {known.image_b} have the same camera centre "
            "in the model; choose two cameras apart"
        )
    return known.distance_m / d_model


def read_colmap(
    source: Path,
    metres_per_unit: float | None = None,
    known_distance: KnownDistance | None = None,
    masks: Path | None = None,
) -> Recording:
    """The recording of a COLMAP project: every image of the model, in the order of their
    names, with X_WC scaled to metres. Images in images/ that the model does not hold (COLMAP
    did not register them) are left out, and said so in the recording's notes."""
    source = Path(source).resolve()
    folder = model_folder(source)
    if folder is None:
        raise ScannerError(
            f"{source}: no COLMAP model (cameras + images .txt or .bin) in sparse/0/, sparse/ "
            "or the folder itself"
        )
    model = read_model(folder)
    where = str(folder)
    if not model.images:
        raise ScannerError(f"{where}: the model holds no images")
    images_dir = source / IMAGES_FOLDER
    ordered = sorted(model.images.values(), key=lambda i: i.name)
    X_WC_model = {i.name: invert(X_CW_of(i, where)) for i in ordered}
    if len(X_WC_model) != len(ordered):
        raise ScannerError(f"{where}: two images share a file name")
    unit_m = _scale(model, X_WC_model, metres_per_unit, known_distance, where)
    paths = []
    for image in ordered:
        path = images_dir / image.name
        if not path.is_file():
            raise ScannerError(
                f"{path}: image {image.image_id} of the model is missing; expected every "
                f"image of {where} in {images_dir}"
            )
        paths.append(path)
    mask_paths = (
        masks_in_order(masks, len(paths), paths) if masks is not None else [None] * len(paths)
    )
    views = []
    for k, image in enumerate(ordered):
        if image.camera_id not in model.cameras:
            raise ScannerError(
                f"{where}: image {image.image_id} ({image.name}) names camera {image.camera_id}, "
                "which the model does not hold"
            )
        X_WC = X_WC_model[image.name].copy()
        X_WC[:3, 3] *= unit_m
        views.append(
            RecordedView(
                index=k,
                image_path=paths[k],
                camera=pinhole_of(model.cameras[image.camera_id], where),
                X_WC=X_WC,
                mask_path=mask_paths[k],
            )
        )
    notes = ()
    if images_dir.is_dir():
        used = {p.resolve() for p in paths}
        extra = [p for p in sorted_files(images_dir, IMAGE_SUFFIXES) if p.resolve() not in used]
        if extra:
            notes = (
                f"{len(extra)} image(s) of {images_dir} are not in the model (not registered by "
                f"COLMAP) and were left out: {', '.join(p.name for p in extra[:3])}"
                + (" ..." if len(extra) > 3 else ""),
            )
    return Recording(tuple(views), FORMAT, source, unit_m, True, None, notes)

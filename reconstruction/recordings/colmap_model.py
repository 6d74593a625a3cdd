"""COLMAP sparse models on disk: cameras and images, as text (cameras.txt, images.txt) or binary
(cameras.bin, images.bin), read and written (the writer makes test models and round trips).

The layout is COLMAP's own (colmap/src/colmap/scene/reconstruction_io.cc; the text files'
headers say the same): an image holds the quaternion (qw, qx, qy, qz) and translation of the
world-to-camera transform X_CW, the camera it was taken with and its file name; its 2D points
are skipped on reading and written empty.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError

# COLMAP's camera models: id -> (name, number of parameters) (colmap/sensor/models.h).
MODELS = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
MODEL_IDS = {name: i for i, (name, _) in MODELS.items()}


@dataclass(frozen=True, eq=False)
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass(frozen=True, eq=False)
class ColmapImage:
    """qvec: (qw, qx, qy, qz) and tvec of X_CW, in the model's unit."""

    image_id: int
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str


@dataclass(frozen=True, eq=False)
class ColmapModel:
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]


def model_files(folder: Path) -> tuple[Path, Path] | None:
    """(cameras, images) files of a model folder, text first, or None when it holds none."""
    folder = Path(folder)
    for ext in (".txt", ".bin"):
        cams, imgs = folder / f"cameras{ext}", folder / f"images{ext}"
        if cams.is_file() and imgs.is_file():
            return cams, imgs
    return None


def read_model(folder: Path) -> ColmapModel:
    files = model_files(folder)
    if files is None:
        raise ScannerError(
            f"{folder}: no cameras.txt + images.txt or cameras.bin + images.bin (a COLMAP model)"
        )
    cams, imgs = files
    if cams.suffix == ".txt":
        return ColmapModel(_read_cameras_text(cams), _read_images_text(imgs))
    return ColmapModel(_read_cameras_binary(cams), _read_images_binary(imgs))


def write_model(folder: Path, model: ColmapModel, binary: bool = False) -> None:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if binary:
        _write_binary(folder, model)
    else:
        _write_text(folder, model)


def _model_name(token: str | int, where: str) -> str:
    if isinstance(token, int):
        if token not in MODELS:
            raise ScannerError(f"{where}: unknown COLMAP camera model id {token}")
        return MODELS[token][0]
    if token not in MODEL_IDS:
        raise ScannerError(f"{where}: unknown COLMAP camera model {token!r}")
    return token


def _lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ScannerError(f"{path}: cannot read the COLMAP text file ({e})") from None
    return [(n, line) for n, line in enumerate(text.splitlines(), 1) if not line.startswith("#")]


def _read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for n, line in _lines(path):
        if not line.strip():
            continue
        where = f"{path}:{n}"
        parts = line.split()
        try:
            camera_id, model, width, height = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = np.array([float(p) for p in parts[4:]])
        except (IndexError, ValueError):
            raise ScannerError(
                f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got {line.strip()!r}"
            ) from None
        model = _model_name(model, where)
        if len(params) != MODELS[MODEL_IDS[model]][1]:
            raise ScannerError(
                f"{where}: {model} has {MODELS[MODEL_IDS[model]][1]} parameters, got {len(params)}"
            )
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cameras


def _read_images_text(path: Path) -> dict[int, ColmapImage]:
    images = {}
    lines = _lines(path)
    # Two lines per image: the pose line and the (possibly empty) line of its 2D points.
    k = 0
    while k < len(lines):
        n, line = lines[k]
        if not line.strip():
            k += 1
            continue
        parts = line.split()
        try:
            image_id = int(parts[0])
            q = np.array([float(x) for x in parts[1:5]])
            t = np.array([float(x) for x in parts[5:8]])
            camera_id = int(parts[8])
            name = " ".join(parts[9:])
            if not name:
                raise IndexError
        except (IndexError, ValueError):
            raise ScannerError(
                f"{path}:{n}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got "
                f"{line.strip()!r}"
            ) from None
        images[image_id] = ColmapImage(image_id, q, t, camera_id, name)
        k += 2
    return images


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as e:
            raise ScannerError(f"{path}: cannot read ({e.strerror})") from None
        self.at = 0

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.at + size > len(self.data):
            raise ScannerError(f"{self.path}: ends early at byte {self.at} (truncated model)")
        values = struct.unpack_from(fmt, self.data, self.at)
        self.at += size
        return values

    def name(self) -> str:
        end = self.data.find(b"\0", self.at)
        if end < 0:
            raise ScannerError(f"{self.path}: ends early in an image name (truncated model)")
        text = self.data[self.at : end].decode("utf-8", errors="replace")
        self.at = end + 1
        return text


def _read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    r = _Reader(path)
    cameras = {}
    for _ in range(r.take("<Q")[0]):
        camera_id, model_id, width, height = r.take("<iiQQ")
        model = _model_name(model_id, f"{path}: camera {camera_id}")
        params = np.array(r.take(f"<{MODELS[model_id][1]}d"))
        cameras[camera_id] = ColmapCamera(camera_id, model, int(width), int(height), params)
    return cameras


def _read_images_binary(path: Path) -> dict[int, ColmapImage]:
    r = _Reader(path)
    images = {}
    for _ in range(r.take("<Q")[0]):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = r.take("<idddddddi")
        name = r.name()
        points = r.take("<Q")[0]
        r.at += points * struct.calcsize("<ddq")
        q, t = np.array([qw, qx, qy, qz]), np.array([tx, ty, tz])
        images[image_id] = ColmapImage(image_id, q, t, camera_id, name)
    if r.at > len(r.data):
        raise ScannerError(f"{path}: ends early in the 2D points (truncated model)")
    return images


def _write_text(folder: Path, model: ColmapModel) -> None:
    cams = ["# Camera list with one line of data per camera:"]
    cams.append("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]")
    for c in model.cameras.values():
        params = " ".join(repr(float(p)) for p in c.params)
        cams.append(f"{c.camera_id} {c.model} {c.width} {c.height} {params}")
    imgs = ["# Image list with two lines of data per image:"]
    imgs.append("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME")
    imgs.append("#   POINTS2D[] as (X, Y, POINT3D_ID)")
    for i in model.images.values():
        pose = " ".join(repr(float(x)) for x in (*i.qvec, *i.tvec))
        imgs.extend([f"{i.image_id} {pose} {i.camera_id} {i.name}", ""])
    (folder / "cameras.txt").write_text("\n".join(cams) + "\n")
    (folder / "images.txt").write_text("\n".join(imgs) + "\n")


def _write_binary(folder: Path, model: ColmapModel) -> None:
    cams = [struct.pack("<Q", len(model.cameras))]
    for c in model.cameras.values():
        cams.append(struct.pack("<iiQQ", c.camera_id, MODEL_IDS[c.model], c.width, c.height))
        cams.append(struct.pack(f"<{len(c.params)}d", *c.params))
    imgs = [struct.pack("<Q", len(model.images))]
    for i in model.images.values():
        imgs.append(struct.pack("<idddddddi", i.image_id, *i.qvec, *i.tvec, i.camera_id))
        imgs.append(i.name.encode() + b"\0" + struct.pack("<Q", 0))
    (folder / "cameras.bin").write_bytes(b"".join(cams))
    (folder / "images.bin").write_bytes(b"".join(imgs))

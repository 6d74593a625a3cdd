"""The scan directory: manifest, one folder per capture, truth kept apart; crash-safe writes.

    SCAN_DIR/
      scan.yaml            manifest (schema, object, config, camera model, nominal X_FC, robot,
                           viewpoints, status, skipped views) -- rewritten atomically, last
      truth.yaml           simulator truth (evaluation only; absent on real hardware)
      truth_mesh.ply       the true object surface in W (evaluation only)
      captures/0007/       one capture: left.png, right.png (lossless), capture.yaml
                           (RGB-D: color.png, depth.png; an imported recording, sensor mono:
                           image.png, optional mask.png and depth.png, the camera and X_WC)
      results/             derived products (never inputs)

A capture exists only once its folder has been renamed from `captures/.tmp-0007` to
`captures/0007`, and that happens after every file in it (capture.yaml last) is on disk; a
killed scan leaves at most a `.tmp-*` folder, which is not a capture and is removed on resume.
"""

from __future__ import annotations

import datetime
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml, yaml_text
from reconstruction.stereo.camera_model import CameraModelError, PinholeCamera
from scanner.scan_dir.results_folder import storage_error

SCAN_SCHEMA = "scanner.scan/1"
CAPTURE_SCHEMA = "scanner.capture/1"
MANIFEST = "scan.yaml"
CAPTURES = "captures"
RESULTS = "results"
# A scan's status only moves forward; an interrupted scan runs again when resumed.
STATUS_RANK = {"running": 0, "interrupted": 0, "captured": 1, "complete": 2}


@dataclass(frozen=True, eq=False)
class Capture:
    """One capture and the robot state it was taken at (what `reconstruct` reads): a stereo
    pair (left, right), or an RGB-D capture (left: the colour image, right None, depth: uint16
    counts of depth_scale_m metres on the depth camera's grid), or a view of an imported
    recording (sensor mono: left the image, right None, its own `camera` and pose `X_WC`, an
    optional `mask`, uint8 0/255, 255 on the object, and an optional depth on the image's grid;
    q_rad is empty, no joints were recorded, and X_WF is the flange pose, or X_WC when the
    recording gave camera poses)."""

    pose_index: int
    pose_count: int
    q_rad: np.ndarray
    X_WF: np.ndarray
    stamp_s: float
    left: np.ndarray
    right: np.ndarray | None
    depth: np.ndarray | None = None
    depth_scale_m: float = 0.0
    mask: np.ndarray | None = None
    camera: PinholeCamera | None = None
    X_WC: np.ndarray | None = None

    def __post_init__(self) -> None:
        if (self.camera is None) != (self.X_WC is None):
            raise AssertionError("a mono capture has its camera and X_WC; others have neither")
        if self.camera is not None and self.right is not None:
            raise AssertionError("a mono capture has one image")
        for a in (self.q_rad, self.X_WF, self.left, self.right, self.depth, self.mask, self.X_WC):
            if a is not None:
                a.setflags(write=False)

    @property
    def sensor(self) -> str:
        if self.camera is not None:
            return "mono"
        return "stereo" if self.depth is None else "rgbd"

    @staticmethod
    def of(pose_index: int, pose_count: int, q_rad, X_WF, images) -> Capture:
        """The capture of what a camera driver delivered (StereoImages or RgbdImages)."""
        if hasattr(images, "depth"):
            return Capture(
                pose_index,
                pose_count,
                q_rad,
                X_WF,
                images.stamp_s,
                images.color,
                None,
                images.depth,
                float(images.depth_scale_m),
            )
        return Capture(
            pose_index, pose_count, q_rad, X_WF, images.stamp_s, images.left, images.right
        )


def write_bytes(path: Path, data: bytes) -> None:
    """One file, flushed to the disk (a full disk raises here, not later)."""
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        write_bytes(tmp, text.encode())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_yaml(path: Path, data: dict) -> None:
    atomic_write_text(path, yaml_text(data))


def _read_yaml(path: Path, what: str) -> dict:
    data = read_yaml(path, what)
    if not isinstance(data, dict):
        raise ScannerError(f"{path}: {what} is not a mapping")
    return data


def _folder(index: int) -> str:
    return f"{index:04d}"


class CaptureStore:
    """Reads and writes one scan directory."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    @property
    def results_dir(self) -> Path:
        return self.root / RESULTS

    # -- creation and manifest --------------------------------------------------------------
    @classmethod
    def create(cls, root: Path, manifest: dict, force: bool = False) -> CaptureStore:
        """A new scan directory. Refuses a non-empty folder unless it is a scan and force is set."""
        root = Path(root)
        if root.exists() and any(root.iterdir()):
            if not (root / MANIFEST).is_file():
                raise ScannerError(
                    f"{root}: exists and is not a scan directory; choose another --out"
                )
            if not force:
                raise ScannerError(
                    f"{root}: already holds a scan; use --resume {root} to continue it, "
                    "or --force to replace it"
                )
            shutil.rmtree(root)
        try:
            (root / CAPTURES).mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ScannerError(f"{root}: cannot create the scan directory ({e.strerror})") from None
        store = cls(root)
        store.write_manifest(
            {"schema": SCAN_SCHEMA, "created": _now(), "status": "running", **manifest}
        )
        return store

    @classmethod
    def open(cls, root: Path) -> CaptureStore:
        store = cls(root)
        manifest = store.read_manifest()
        if manifest.get("schema") != SCAN_SCHEMA:
            raise ScannerError(
                f"{store.manifest_path}: schema is {manifest.get('schema')!r}, "
                f"expected {SCAN_SCHEMA!r}"
            )
        return store

    def read_manifest(self) -> dict:
        if not self.manifest_path.is_file():
            raise ScannerError(f"{self.root}: not a scan directory (no {MANIFEST})")
        return _read_yaml(self.manifest_path, "scan manifest")

    def write_manifest(self, manifest: dict) -> None:
        atomic_write_yaml(self.manifest_path, manifest)

    def update_manifest(self, **changes) -> dict:
        manifest = self.read_manifest()
        if "status" in changes:
            before, after = manifest.get("status", "running"), changes["status"]
            if STATUS_RANK[after] < STATUS_RANK[before]:
                raise AssertionError(f"scan status may not go back from {before} to {after}")
        manifest.update(changes)
        manifest["updated"] = _now()
        self.write_manifest(manifest)
        return manifest

    # -- captures ---------------------------------------------------------------------------
    def remove_partial_captures(self) -> list[str]:
        """Delete `.tmp-*` folders: interrupted writes that never became captures."""
        removed = []
        for tmp in sorted((self.root / CAPTURES).glob(".tmp-*")):
            shutil.rmtree(tmp)
            removed.append(tmp.name)
        return removed

    def captured_indices(self) -> list[int]:
        out = []
        for d in sorted((self.root / CAPTURES).iterdir()):
            if d.is_dir() and d.name.isdigit() and (d / "capture.yaml").is_file():
                out.append(int(d.name))
        return out

    def write_capture(self, capture: Capture) -> Path:
        final = self.root / CAPTURES / _folder(capture.pose_index)
        if final.exists():
            raise ScannerError(f"{final}: capture {capture.pose_index} exists; not overwriting")
        tmp = self.root / CAPTURES / f".tmp-{_folder(capture.pose_index)}"
        if tmp.exists():
            shutil.rmtree(tmp)
        try:
            tmp.mkdir()
            self._write_capture_files(tmp, capture)
            _fsync_dir(tmp)
            os.rename(tmp, final)
            _fsync_dir(final.parent)
        except OSError as e:
            shutil.rmtree(tmp, ignore_errors=True)
            raise storage_error(final, e) from None
        return final

    @staticmethod
    def _write_capture_files(tmp: Path, capture: Capture) -> None:
        if capture.sensor == "mono":
            files = {"image": ("image.png", capture.left)}
            for key, image in (("mask", capture.mask), ("depth", capture.depth)):
                if image is not None:
                    files[key] = (f"{key}.png", image)
        elif capture.sensor == "rgbd":
            files = {"color": ("color.png", capture.left), "depth": ("depth.png", capture.depth)}
        else:
            files = {"left": ("left.png", capture.left), "right": ("right.png", capture.right)}
        for name, image in files.values():
            # PNG is lossless for 8-bit colour and for 16-bit depth counts alike.
            data = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            ok, png = cv2.imencode(".png", data)
            if not ok:
                raise ScannerError(f"capture {capture.pose_index}: image could not be encoded")
            write_bytes(tmp / name, png.tobytes())
        meta = {
            "schema": CAPTURE_SCHEMA,
            "pose_index": capture.pose_index,
            "pose_count": capture.pose_count,
            "q_rad": [float(v) for v in capture.q_rad],
            "X_WF": capture.X_WF.tolist(),
            "stamp_s": float(capture.stamp_s),
            "sensor": capture.sensor,
            **{key: name for key, (name, _) in files.items()},
            "image_size": [int(capture.left.shape[1]), int(capture.left.shape[0])],
        }
        if capture.depth is not None:
            meta["depth_size"] = [int(capture.depth.shape[1]), int(capture.depth.shape[0])]
            meta["depth_scale_m"] = float(capture.depth_scale_m)
        if capture.sensor == "mono":
            meta["camera"] = mono_camera_to_dict(capture.camera)
            meta["X_WC"] = capture.X_WC.tolist()
        atomic_write_yaml(tmp / "capture.yaml", meta)

    def capture_stamp_s(self, index: int) -> float:
        """When capture `index` was taken (its metadata alone); NaN when unreadable (reading
        the capture itself then says why)."""
        try:
            meta = _read_yaml(self.root / CAPTURES / _folder(index) / "capture.yaml", "capture")
            return float(meta["stamp_s"])
        except (ScannerError, KeyError, TypeError, ValueError):
            return math.nan

    def read_capture(self, index: int) -> Capture:
        """One capture, validated; a damaged capture raises ScannerError naming the problem."""
        d = self.root / CAPTURES / _folder(index)
        meta = _read_yaml(d / "capture.yaml", "capture metadata")
        sensor = meta.get("sensor", "stereo")
        try:
            # A recording's view has no joints (q_rad empty or absent).
            q = np.array(meta["q_rad"] if sensor != "mono" else meta.get("q_rad", []), float)
            X_WF = np.array(meta["X_WF"], dtype=float)
            width, height = meta["image_size"]
            stamp = float(meta["stamp_s"])
            count = int(meta["pose_count"])
            if int(meta["pose_index"]) != index:
                raise ScannerError(f"{d}: pose_index {meta['pose_index']} != folder {index}")
        except (KeyError, TypeError, ValueError) as e:
            raise ScannerError(f"{d / 'capture.yaml'}: missing or malformed field ({e})") from None
        # One value per joint of the scan's arm (the manifest's robot and config name it).
        if q.ndim != 1 or not (q.size or sensor == "mono") or not np.all(np.isfinite(q)):
            raise ScannerError(
                f"{d / 'capture.yaml'}: q_rad must be a list of finite joint positions"
            )
        if X_WF.shape != (4, 4) or not np.all(np.isfinite(X_WF)):
            raise ScannerError(f"{d / 'capture.yaml'}: X_WF must be a finite 4x4 matrix")
        if sensor == "mono":
            return _read_mono(d, meta, index, count, q, X_WF, stamp, width, height)
        if sensor == "rgbd":
            color = _read_rgb(d / str(meta.get("color", "color.png")), width, height)
            depth, scale = read_depth(d, meta)
            return Capture(index, count, q, X_WF, stamp, color, None, depth, scale)
        if sensor != "stereo":
            raise ScannerError(
                f"{d / 'capture.yaml'}: sensor: expected 'stereo', 'rgbd' or 'mono', got {sensor!r}"
            )
        images = [
            _read_rgb(d / str(meta.get(name, f"{name}.png")), width, height)
            for name in ("left", "right")
        ]
        return Capture(index, count, q, X_WF, stamp, images[0], images[1])


def mono_camera_to_dict(camera: PinholeCamera) -> dict:
    return {
        "K": camera.K.tolist(),
        "distortion": camera.distortion.tolist(),
        "width": camera.width,
        "height": camera.height,
    }


def mono_camera_from_dict(d, where: str) -> PinholeCamera:
    if not isinstance(d, dict) or any(k not in d for k in ("K", "distortion", "width", "height")):
        raise ScannerError(f"{where}: camera: expected K, distortion, width and height")
    w, h = d["width"], d["height"]
    if not (isinstance(w, int) and isinstance(h, int)) or isinstance(w, bool):
        raise ScannerError(f"{where}: camera: width and height must be whole pixels")
    try:
        return PinholeCamera(d["K"], d["distortion"], w, h)
    except CameraModelError as e:
        raise ScannerError(f"{where}: camera: {e}") from None


def _read_mono(
    d: Path, meta: dict, index: int, count: int, q, X_WF, stamp: float, width: int, height: int
) -> Capture:
    """A view of an imported recording: its image, camera and X_WC, an optional mask and
    depth, each checked against the image size."""
    where = d / "capture.yaml"
    camera = mono_camera_from_dict(meta.get("camera"), str(where))
    if (camera.width, camera.height) != (width, height):
        raise ScannerError(
            f"{where}: camera is {camera.width}x{camera.height}, image_size {width}x{height}"
        )
    try:
        X_WC = np.array(meta["X_WC"], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise ScannerError(f"{where}: X_WC: expected a finite 4x4 matrix") from None
    if X_WC.shape != (4, 4) or not np.all(np.isfinite(X_WC)):
        raise ScannerError(f"{where}: X_WC: expected a finite 4x4 matrix")
    image = _read_rgb(d / str(meta.get("image", "image.png")), width, height)
    mask = None
    if "mask" in meta:
        path = d / str(meta["mask"])
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise ScannerError(f"{path}: missing or unreadable mask")
        if mask.shape != (height, width):
            raise ScannerError(
                f"{path}: mask is {mask.shape[1]}x{mask.shape[0]}, expected {width}x{height}"
            )
    depth, scale = (None, 0.0) if "depth" not in meta else read_depth(d, meta)
    return Capture(index, count, q, X_WF, stamp, image, None, depth, scale, mask, camera, X_WC)


def _read_rgb(path: Path, width: int, height: int) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ScannerError(f"{path}: missing or unreadable image")
    if bgr.shape[:2] != (height, width):
        raise ScannerError(
            f"{path}: image is {bgr.shape[1]}x{bgr.shape[0]}, expected {width}x{height}"
        )
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def read_depth(folder: Path, meta: dict) -> tuple[np.ndarray, float]:
    """An RGB-D capture's depth counts and their unit, checked against its capture.yaml."""
    where = folder / "capture.yaml"
    scale = meta.get("depth_scale_m")
    if isinstance(scale, bool) or not isinstance(scale, int | float):
        raise ScannerError(
            f"{where}: depth_scale_m: expected the depth unit in metres, got {scale!r}"
        )
    if not (np.isfinite(scale) and scale > 0):
        raise ScannerError(f"{where}: depth_scale_m: expected a positive number, got {scale}")
    size = meta.get("depth_size")
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(n, int) for n in size)):
        raise ScannerError(f"{where}: depth_size: expected [width, height], got {size!r}")
    path = folder / str(meta.get("depth", "depth.png"))
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise ScannerError(f"{path}: missing or unreadable depth image")
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ScannerError(f"{path}: expected a 16-bit single-channel depth image")
    if depth.shape != (size[1], size[0]):
        raise ScannerError(
            f"{path}: depth image is {depth.shape[1]}x{depth.shape[0]}, expected "
            f"{size[0]}x{size[1]}"
        )
    return depth, float(scale)


def require_same_settings(where: Path, what: str, saved: dict, wanted: dict) -> None:
    """Refuse to resume a run (`what`: scan, calibration) whose recorded settings differ from
    the ones asked for now, naming the top-level keys that differ."""
    differing = sorted(k for k in set(saved) | set(wanted) if saved.get(k) != wanted.get(k))
    if differing:
        raise ScannerError(
            f"{where}: this {what} was started with a different configuration: different "
            f"{', '.join(differing)}; resume with the same settings or start a new {what}"
        )


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")

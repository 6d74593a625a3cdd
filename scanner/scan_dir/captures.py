"""The scan directory: manifest, one folder per capture, truth kept apart; crash-safe writes.

    SCAN_DIR/
      scan.yaml            manifest (schema, object, config, camera model, nominal X_FC, robot,
                           viewpoints, status, skipped views) -- rewritten atomically, last
      truth.yaml           simulator truth (evaluation only; absent on real hardware)
      truth_mesh.ply       the true object surface in W (evaluation only)
      captures/0007/       one capture: left.png, right.png (lossless), capture.yaml
                           (RGB-D: color.png, depth.png; an imported recording, sensor mono:
                           image.png, optional mask.png and depth.png, the camera and X_WC;
                           each format's files: capture_formats.py)
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
from pathlib import Path

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml, yaml_text
from scanner.scan_dir.capture_formats import (
    CAPTURE_FORMATS,
    Capture,
    CaptureHeader,
    format_names,
)
from scanner.scan_dir.results_folder import storage_error

SCAN_SCHEMA = "scanner.scan/1"
CAPTURE_SCHEMA = "scanner.capture/1"
MANIFEST = "scan.yaml"
CAPTURES = "captures"
RESULTS = "results"
__all__ = ["Capture", "CaptureStore"]  # Capture lives with the capture formats
# A scan's status only moves forward; an interrupted scan runs again when resumed.
STATUS_RANK = {"running": 0, "interrupted": 0, "captured": 1, "complete": 2}


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
        form = CAPTURE_FORMATS[capture.sensor]
        files = form.files(capture)
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
        meta.update(form.own_fields(capture))
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
        form = CAPTURE_FORMATS.get(sensor) if isinstance(sensor, str) else None
        joints = form is None or form.joints_required
        try:
            # A recording's view has no joints (q_rad empty or absent).
            q = np.array(meta["q_rad"] if joints else meta.get("q_rad", []), float)
            X_WF = np.array(meta["X_WF"], dtype=float)
            width, height = meta["image_size"]
            stamp = float(meta["stamp_s"])
            count = int(meta["pose_count"])
            if int(meta["pose_index"]) != index:
                raise ScannerError(f"{d}: pose_index {meta['pose_index']} != folder {index}")
        except (KeyError, TypeError, ValueError) as e:
            raise ScannerError(f"{d / 'capture.yaml'}: missing or malformed field ({e})") from None
        # One value per joint of the scan's arm (the manifest's robot and config name it).
        if q.ndim != 1 or not (q.size or not joints) or not np.all(np.isfinite(q)):
            raise ScannerError(
                f"{d / 'capture.yaml'}: q_rad must be a list of finite joint positions"
            )
        if X_WF.shape != (4, 4) or not np.all(np.isfinite(X_WF)):
            raise ScannerError(f"{d / 'capture.yaml'}: X_WF must be a finite 4x4 matrix")
        if form is None:
            raise ScannerError(
                f"{d / 'capture.yaml'}: sensor: expected {format_names()}, got {sensor!r}"
            )
        return form.read(CaptureHeader(d, meta, index, count, q, X_WF, stamp, width, height))


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

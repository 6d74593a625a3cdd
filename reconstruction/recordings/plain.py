"""The plain recording form: one YAML file (`recording.yaml`) listing the views, for systems that
can write their own poses and intrinsics (docs/file-formats.md, "A recording in the plain form").

    unit_m: 0.001              # metres per unit of every translation below (required)
    K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]   # default for the views (pixels)
    distortion: [k1, k2, p1, p2, k3]           # default for the views (OpenCV; optional)
    X_FC: 4x4                  # the camera on the flange, when the views give X_WF
    depth_unit_m: 0.001        # default for the views' depth images
    views:
      - image: images/000.png  # paths relative to this file
        X_WC: 4x4              # the camera's pose, or X_WF (the flange's) with X_FC above
        K, distortion, image_size: [w, h], mask: ..., depth: ..., depth_unit_m: ...  (optional)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml
from reconstruction.recordings.recording import RecordedView, Recording, image_size
from reconstruction.stereo.camera_model import CameraModelError, PinholeCamera

FORMAT = "plain"
FILE_NAME = "recording.yaml"
TOP_KEYS = {"schema", "unit_m", "K", "distortion", "image_size", "X_FC", "depth_unit_m", "views"}
VIEW_KEYS = {
    "image", "K", "distortion", "image_size", "X_WC", "X_WF", "mask", "depth", "depth_unit_m"
}  # fmt: skip
# Rotations written with a few decimals are not orthonormal to machine precision: those within
# this of a rotation are projected onto the nearest one; further off, the matrix is refused.
ROTATION_TOLERANCE = 1e-4


def recording_file(source: Path) -> Path | None:
    """The plain-form file SOURCE names (the file, or FILE_NAME in the folder), or None."""
    source = Path(source)
    if source.is_file() and source.suffix.lower() in (".yaml", ".yml"):
        return source
    if (source / FILE_NAME).is_file():
        return source / FILE_NAME
    return None


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ScannerError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _matrix(value, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ScannerError(f"{where}: expected numbers of shape {shape}, got {value!r}") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ScannerError(f"{where}: expected finite numbers of shape {list(shape)}")
    return a


def rigid(value, unit_m: float, where: str) -> np.ndarray:
    """A 4x4 rigid transform of the file, its translation scaled to metres; a rotation block
    off by rounding is projected onto the nearest rotation."""
    X = _matrix(value, (4, 4), where)
    if not np.allclose(X[3], [0, 0, 0, 1]):
        raise ScannerError(f"{where}: the last row must be [0, 0, 0, 1], got {X[3].tolist()}")
    R = X[:3, :3]
    U, _, Vt = np.linalg.svd(R)
    nearest = U @ Vt
    if np.linalg.det(nearest) < 0 or np.abs(R - nearest).max() > ROTATION_TOLERANCE:
        raise ScannerError(
            f"{where}: the rotation block is not a rotation (orthonormal, det +1); expected a "
            "rigid transform"
        )
    X = X.copy()
    X[:3, :3] = nearest
    X[:3, 3] *= unit_m
    return X


def _path(folder: Path, value, where: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise ScannerError(f"{where}: expected a file path (relative to the recording file)")
    return (folder / value).resolve()


def _unknown(d: dict, known: set[str], where: str) -> None:
    extra = sorted(set(d) - known)
    if extra:
        raise ScannerError(
            f"{where}: unknown key(s) {', '.join(extra)}; expected {', '.join(sorted(known))}"
        )


def _view(i: int, d, top: dict, folder: Path, unit_m: float, where: str) -> RecordedView:
    where = f"{where}: views[{i}]"
    if not isinstance(d, dict):
        raise ScannerError(f"{where}: expected a mapping with image and X_WC or X_WF")
    _unknown(d, VIEW_KEYS, where)
    if "image" not in d:
        raise ScannerError(f"{where}: missing image")
    image = _path(folder, d["image"], f"{where}.image")
    if "K" not in d and "K" not in top:
        raise ScannerError(f"{where}: missing K (per view, or at the top for every view)")
    K = _matrix(d.get("K", top.get("K")), (3, 3), f"{where}.K")
    dist = _matrix(
        d.get("distortion", top.get("distortion", [0.0] * 5)), (5,), f"{where}.distortion"
    )
    size = d.get("image_size", top.get("image_size"))
    if size is None:
        width, height = image_size(image)
    elif isinstance(size, list) and len(size) == 2 and all(isinstance(n, int) for n in size):
        width, height = size
    else:
        raise ScannerError(f"{where}.image_size: expected [width, height] in pixels, got {size!r}")
    try:
        camera = PinholeCamera(K, dist, width, height)
    except CameraModelError as e:
        raise ScannerError(f"{where}: {e}") from None
    given = [k for k in ("X_WC", "X_WF") if k in d]
    if len(given) != 1:
        raise ScannerError(f"{where}: expected exactly one of X_WC and X_WF, got {given or 'none'}")
    X_WF = None
    if given == ["X_WF"]:
        if "X_FC" not in top:
            raise ScannerError(f"{where}: X_WF needs X_FC at the top of the file")
        X_WF = rigid(d["X_WF"], unit_m, f"{where}.X_WF")
        X_WC = X_WF @ rigid(top["X_FC"], unit_m, f"{where}: X_FC")
    else:
        X_WC = rigid(d["X_WC"], unit_m, f"{where}.X_WC")
    mask = _path(folder, d["mask"], f"{where}.mask") if "mask" in d else None
    depth, depth_scale_m = None, 0.0
    if "depth" in d:
        depth = _path(folder, d["depth"], f"{where}.depth")
        if "depth_unit_m" not in d and "depth_unit_m" not in top:
            raise ScannerError(f"{where}: a depth image needs depth_unit_m (metres per count)")
        depth_scale_m = _number(
            d.get("depth_unit_m", top.get("depth_unit_m")), f"{where}.depth_unit_m"
        )
        if depth_scale_m <= 0:
            raise ScannerError(f"{where}.depth_unit_m: expected a positive number")
    return RecordedView(i, image, camera, X_WC, mask, depth, depth_scale_m, X_WF)


def read_plain(source: Path, masks: Path | None = None) -> Recording:
    """The recording a plain-form file describes. masks: not used (the file names each view's
    mask); a folder given is refused rather than ignored."""
    path = recording_file(source)
    if path is None:
        raise ScannerError(f"{source}: no {FILE_NAME}; expected a plain recording file")
    if masks is not None:
        raise ScannerError(f"--masks: the plain form names each view's mask in {path}")
    path = path.resolve()
    where = str(path)
    top = read_yaml(path, "recording file")
    if not isinstance(top, dict):
        raise ScannerError(f"{where}: expected a mapping with unit_m and views")
    _unknown(top, TOP_KEYS, where)
    if "unit_m" not in top:
        raise ScannerError(f"{where}: missing unit_m (metres per unit of the translations)")
    unit_m = _number(top["unit_m"], f"{where}: unit_m")
    if unit_m <= 0:
        raise ScannerError(f"{where}: unit_m: expected a positive number, got {unit_m}")
    items = top.get("views")
    if not isinstance(items, list) or not items:
        raise ScannerError(f"{where}: views: expected a list of views")
    views = tuple(_view(i, d, top, path.parent, unit_m, where) for i, d in enumerate(items))
    kinds = {v.X_WF is None for v in views}
    if len(kinds) > 1:
        raise ScannerError(f"{where}: views mix X_WC and X_WF; expected one kind for all")
    camera_poses_given = kinds == {True}
    X_FC = None if camera_poses_given else rigid(top["X_FC"], unit_m, f"{where}: X_FC")
    if camera_poses_given and "X_FC" in top:
        raise ScannerError(f"{where}: X_FC given, but the views give X_WC (X_FC applies to X_WF)")
    return Recording(views, FORMAT, path, unit_m, camera_poses_given, X_FC)

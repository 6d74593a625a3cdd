"""A recording of another system, read into one record: per view an image, its camera (K,
distortion, size) and its pose X_WC in metres, optionally a mask, a depth image and the flange
pose; and the checks every recording passes before anything is written from it.

Frames: W is the recording's world frame (a robot base, DTU's first camera, a COLMAP model's
origin: whatever the source used, scaled to metres); C is the camera's optical frame (OpenCV:
+z forward, +x right, +y down); F the flange when the source gives flange poses and X_FC.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import check_pose
from reconstruction.stereo.camera_model import PinholeCamera

# Two views whose camera centres are closer than this have no baseline between them: a
# duplicate entry or a camera that did not move, which the reconstruction cannot use as a pair.
MIN_BASELINE_M = 0.001


def _frozen_pose(X: np.ndarray | None, name: str) -> np.ndarray | None:
    if X is None:
        return None
    X = np.array(check_pose(X, name), dtype=float)
    X.setflags(write=False)
    return X


@dataclass(frozen=True, eq=False)
class RecordedView:
    """One view of a recording. X_WC: the camera's pose in W (4x4, metres); X_WF: the flange's
    (None when the source gives camera poses); depth_scale_m: metres per depth count (0: no
    depth image)."""

    index: int
    image_path: Path
    camera: PinholeCamera
    X_WC: np.ndarray
    mask_path: Path | None = None
    depth_path: Path | None = None
    depth_scale_m: float = 0.0
    X_WF: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "X_WC", _frozen_pose(self.X_WC, f"view {self.index}: X_WC"))
        object.__setattr__(self, "X_WF", _frozen_pose(self.X_WF, f"view {self.index}: X_WF"))
        if (self.depth_path is None) != (self.depth_scale_m == 0.0):
            raise ScannerError(
                f"view {self.index}: a depth image needs its unit (depth_scale_m > 0), and a "
                "unit needs a depth image"
            )


@dataclass(frozen=True, eq=False)
class Recording:
    """A whole recording. format: the reader's name (idr, colmap, plain); source: the folder or
    file it was read from; metres_per_unit: the scale applied to the source's lengths;
    camera_poses_given: the source gave X_WC (else X_WF and X_FC, X_WC = X_WF @ X_FC);
    X_FC: the camera on the flange (None when camera poses are given); notes: what the reader
    left out or assumed, one line each, for the user."""

    views: tuple[RecordedView, ...]
    format: str
    source: Path
    metres_per_unit: float
    camera_poses_given: bool
    X_FC: np.ndarray | None = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "X_FC", _frozen_pose(self.X_FC, f"{self.source}: X_FC"))

    @property
    def has_masks(self) -> bool:
        return any(v.mask_path is not None for v in self.views)


def image_size(path: Path, what: str = "image") -> tuple[int, int]:
    """(width, height) of an image file; ScannerError naming it when it cannot be read."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ScannerError(f"{path}: missing or unreadable {what}")
    return int(image.shape[1]), int(image.shape[0])


def read_image_rgb(path: Path) -> np.ndarray:
    """An image as 8-bit RGB (what the product's captures hold)."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ScannerError(f"{path}: missing or unreadable image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def read_mask(path: Path) -> np.ndarray:
    """A mask as uint8 0/255 (255: the object). Masks come as grey or RGB, 0/255 or 0/1, and
    with blurred edges from resizing: anything above half of the file's range is the object."""
    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None:
        raise ScannerError(f"{path}: missing or unreadable mask")
    if mask.ndim == 3:
        mask = mask[..., :3].max(axis=2)
    top = float(mask.max())
    if top <= 0:
        return np.zeros(mask.shape, np.uint8)
    full = 1.0 if top <= 1 else float(np.iinfo(mask.dtype).max) if mask.dtype.kind == "u" else top
    return np.where(mask > full / 2, 255, 0).astype(np.uint8)


def read_depth_counts(path: Path) -> np.ndarray:
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise ScannerError(f"{path}: missing or unreadable depth image")
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ScannerError(f"{path}: expected a 16-bit single-channel depth image (PNG)")
    return depth


def _check_sizes(view: RecordedView) -> None:
    cam = view.camera
    w, h = image_size(view.image_path)
    if (w, h) != (cam.width, cam.height):
        raise ScannerError(
            f"{view.image_path}: image is {w}x{h} px, the camera of view {view.index} says "
            f"{cam.width}x{cam.height}"
        )
    if view.mask_path is not None:
        mw, mh = image_size(view.mask_path, "mask")
        if (mw, mh) != (w, h):
            raise ScannerError(
                f"{view.mask_path}: mask is {mw}x{mh} px, expected the size of its image "
                f"{view.image_path.name} ({w}x{h})"
            )
    if view.depth_path is not None:
        depth = read_depth_counts(view.depth_path)
        if depth.shape != (h, w):
            raise ScannerError(
                f"{view.depth_path}: depth image is {depth.shape[1]}x{depth.shape[0]} px, "
                f"expected the size of its image {view.image_path.name} ({w}x{h})"
            )


def check_baselines(views: tuple[RecordedView, ...], where: str, min_baseline_m: float) -> None:
    """Refuse two views whose camera centres are closer than min_baseline_m."""
    p_WC = np.array([v.X_WC[:3, 3] for v in views])
    pairs = sorted(cKDTree(p_WC).query_pairs(min_baseline_m)) if len(p_WC) > 1 else []
    if pairs:
        i, j = pairs[0]
        d_mm = 1000 * float(np.linalg.norm(p_WC[i] - p_WC[j]))
        raise ScannerError(
            f"{where}: views {views[i].index} ({views[i].image_path.name}) and {views[j].index} "
            f"({views[j].image_path.name}) have camera centres {d_mm:.3g} mm apart, expected at "
            f"least {1000 * min_baseline_m:g} mm (the same pose twice: no baseline)"
        )


def check_recording(rec: Recording, min_baseline_m: float = MIN_BASELINE_M) -> None:
    """Every check a recording passes before it is written (the readers check their own files'
    structure first): at least two views; each image, mask and depth image readable and of the
    size its camera says; finite rigid poses; a positive scale; no two views at the same pose;
    the principal point inside the image."""
    where = str(rec.source)
    if not (np.isfinite(rec.metres_per_unit) and rec.metres_per_unit > 0):
        raise ScannerError(
            f"{where}: metres per unit must be a positive number, got {rec.metres_per_unit}"
        )
    if len(rec.views) < 2:
        raise ScannerError(
            f"{where}: {len(rec.views)} view(s), expected at least two (a model needs a baseline)"
        )
    if [v.index for v in rec.views] != list(range(len(rec.views))):
        raise AssertionError("a reader numbers its views 0, 1, ... in order")
    masks = [v.mask_path is not None for v in rec.views]
    if any(masks) and not all(masks):
        missing = rec.views[masks.index(False)]
        raise ScannerError(f"{where}: view {missing.index} has no mask; expected all or none")
    if rec.camera_poses_given != (rec.X_FC is None):
        raise AssertionError("X_FC is given exactly when the source gives flange poses")
    for v in rec.views:
        if (v.X_WF is None) != rec.camera_poses_given:
            raise AssertionError("X_WF is given exactly when the source gives flange poses")
        cx, cy = v.camera.K[0, 2], v.camera.K[1, 2]
        if not (0 <= cx <= v.camera.width and 0 <= cy <= v.camera.height):
            raise ScannerError(
                f"{where}: view {v.index} ({v.image_path.name}): principal point ({cx:.1f}, "
                f"{cy:.1f}) px lies outside the {v.camera.width}x{v.camera.height} image; "
                "expected K in pixels of this image"
            )
        _check_sizes(v)
    check_baselines(rec.views, where, min_baseline_m)


def sorted_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """The files of `folder` with one of `suffixes` (case-insensitive), sorted by name."""
    return sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in suffixes)


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def masks_in_order(folder: Path, count: int, images: list[Path]) -> list[Path]:
    """The masks of `folder` sorted by name, one per image in the images' order (mask names
    need not match: 000.png beside 000000.png both occur); their count must match."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ScannerError(f"{folder}: masks folder not found")
    masks = sorted_files(folder, IMAGE_SUFFIXES)
    if len(masks) != count:
        raise ScannerError(
            f"{folder}: {len(masks)} mask(s), expected one per image ({count}, in the order of "
            f"the images' names: {images[0].name} ...)"
        )
    return masks

"""`scanner calibrate --offline DIR`: calibrate from recorded data, either a calibration (or
scan) directory made by this tool or another system's images and robot pose files.

Results go to OUT/results/: calibration.yaml (what `scan` and `reconstruct` read with
--calibration), report.json and report.txt.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from reconstruction.calibration.boards import BoardSpec, detect_board
from reconstruction.calibration.file import load_calibration
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.pose_files import PoseFormat, read_pose_file, read_pose_list
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.camera_model import PinholeCamera, StereoCamera, stereo_camera_from_dict
from reconstruction.errors import ScannerError
from reconstruction.yaml_files import read_yaml
from robots.truth import load_truth
from scanner.calibrate.report import build_report, truth_errors, write_results
from scanner.calibrate.solve import CalibrationRun, solve
from scanner.captures import CaptureStore
from scanner.typed_yaml import from_dict

IMAGE_SUFFIXES = (".png", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff")


def _natural_key(path: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def _read_gray(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ScannerError(f"{path}: missing or unreadable image")
    return image


def _detect(board: BoardSpec, image: np.ndarray, settings: CalibrationSettings):
    return detect_board(board, image, settings.min_points_per_view)


@dataclass(frozen=True)
class OfflineOptions:
    """How to read a folder recorded by another system.

    board: None to take it from a calibration directory's manifest. pose_format: the robot pose
    convention. pose_file: one pose per line, in the natural order of the images; without it
    every image has a pose file with its stem and `pose_suffix`. intrinsics: a camera file
    (scanner calibration or stereo camera YAML, or text with K row by row then k1 k2 p1 p2 k3);
    None estimates them from the board views.
    """

    board: BoardSpec | None = None
    pose_format: PoseFormat = field(default_factory=PoseFormat)
    pose_file: Path | None = None
    pose_suffix: str = ".txt"
    intrinsics: Path | None = None


def load_intrinsics(path: Path) -> StereoCamera | PinholeCamera:
    """A stereo or single camera from a scanner YAML file or a text file of numbers."""
    path = Path(path)
    if not path.is_file():
        raise ScannerError(f"{path}: no such intrinsics file")
    if path.suffix.lower() in (".yaml", ".yml"):
        d = read_yaml(path, "intrinsics")
        if isinstance(d, dict) and d.get("schema") == "scanner.calibration/1":
            cal = load_calibration(path)
            return cal.stereo or cal.camera
        return stereo_camera_from_dict(d, str(path))
    try:
        values = np.array([float(t) for t in re.split(r"[\s,;]+", path.read_text().strip()) if t])
    except ValueError:
        raise ScannerError(f"{path}: expected numbers (K row by row, then distortion)") from None
    if len(values) < 14:
        raise ScannerError(
            f"{path}: found {len(values)} numbers, need 14 (K 3x3 row by row, then k1 k2 p1 p2 k3)"
        )
    K = values[:9].reshape(3, 3)
    # The image size is not in such files; it is checked against the images by the caller.
    return PinholeCamera(K, values[9:14], 1, 1)


def _with_size(camera: PinholeCamera, size: tuple[int, int]) -> PinholeCamera:
    return PinholeCamera(camera.K, camera.distortion, int(size[0]), int(size[1]))


def _foreign_observations(
    root: Path, options: OfflineOptions, settings: CalibrationSettings
) -> tuple[list[PoseObservation], tuple[int, int]]:
    """Images (and left/ right/ subfolders for a stereo pair) with their robot poses."""
    stereo = (root / "left").is_dir() and (root / "right").is_dir()
    image_dir = root / "left" if stereo else root
    images = sorted(
        (p for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=_natural_key
    )
    if not images:
        raise ScannerError(
            f"{root}: no images ({', '.join(IMAGE_SUFFIXES)}) found; expected images with pose "
            "files, or left/ and right/ folders"
        )
    if options.board is None:
        raise ScannerError(f"{root}: give the board (--board, --board-size, --board-spacing)")
    if options.pose_file is not None:
        poses = read_pose_list(options.pose_file, options.pose_format)
        if len(poses) != len(images):
            raise ScannerError(
                f"{options.pose_file}: {len(poses)} poses for {len(images)} images; one pose per "
                "image, in the images' name order"
            )
    else:
        poses = []
        for image in images:
            pose_path = root / (image.stem + options.pose_suffix)
            if not pose_path.is_file():
                raise ScannerError(
                    f"{pose_path}: missing pose file for {image.name} (or give --pose-file)"
                )
            poses.append(read_pose_file(pose_path, options.pose_format))
    observations, size = [], None
    for image, X_WF in zip(images, poses):
        gray = _read_gray(image)
        this_size = (gray.shape[1], gray.shape[0])
        if size is not None and this_size != size:
            raise ScannerError(f"{image}: image size {this_size} differs from the first {size}")
        size = this_size
        right = None
        if stereo:
            right_path = root / "right" / image.name
            right = _detect(options.board, _read_gray(right_path), settings)
        left = _detect(options.board, gray, settings)
        observations.append(PoseObservation(image.stem, X_WF, left, right))
    return observations, size


def _store_observations(
    store: CaptureStore, board: BoardSpec, settings: CalibrationSettings
) -> tuple[list[PoseObservation], tuple[int, int]]:
    observations, size = [], None
    indices = store.captured_indices()
    if not indices:
        raise ScannerError(f"{store.root}: the directory holds no captures")
    for index in indices:
        capture = store.read_capture(index)
        size = (capture.left.shape[1], capture.left.shape[0])
        observations.append(
            PoseObservation(
                f"{index:04d}",
                capture.X_WF,
                _detect(board, capture.left, settings),
                _detect(board, capture.right, settings),
            )
        )
    return observations, size


def _truth_of(root: Path) -> tuple[np.ndarray, StereoCamera] | None:
    path = root / "truth.yaml"
    if not path.is_file():
        return None

    truth, _ = load_truth(path)
    return truth.X_FC, truth.stereo


def calibrate_directory(
    root: Path,
    options: OfflineOptions = OfflineOptions(),
    settings: CalibrationSettings = CalibrationSettings(),
    out_dir: Path | None = None,
    extra_report: dict | None = None,
) -> CalibrationRun:
    """Calibrate from a directory: this tool's calibration directory, or another system's
    images + poses. Results go to out_dir/results (default: root/results for a calibration
    directory; root is never modified otherwise)."""
    root = Path(root)
    if not root.is_dir():
        raise ScannerError(f"{root}: no such directory")
    intrinsics = None if options.intrinsics is None else load_intrinsics(options.intrinsics)
    if (root / "scan.yaml").is_file():
        store = CaptureStore.open(root)
        manifest = store.read_manifest()
        board = options.board
        if board is None:
            if "board" not in manifest:
                raise ScannerError(f"{store.manifest_path}: no board recorded; give --board")
            board = from_dict(BoardSpec, manifest["board"], f"{store.manifest_path}:board")
        observations, size = _store_observations(store, board, settings)
        source = "simulation" if (root / "truth.yaml").is_file() else f"offline:{root}"
        out_dir = out_dir or root
    else:
        observations, size = _foreign_observations(root, options, settings)
        board = options.board
        source = f"offline:{root}"
        if out_dir is None:
            raise ScannerError("offline calibration of another system's folder needs --out DIR")
    if isinstance(intrinsics, PinholeCamera) and intrinsics.width == 1:
        intrinsics = _with_size(intrinsics, size)
    solution = solve(board, observations, size, settings, intrinsics, source)
    truth = _truth_of(root)
    errors = None if truth is None else truth_errors(solution, *truth)
    report = build_report(solution, errors, extra_report)
    path = write_results(out_dir, solution, report)
    return CalibrationRun(Path(out_dir), path, report, solution)

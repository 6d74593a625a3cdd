"""`scanner calibrate --offline DIR`: calibrate from recorded data, either a calibration (or
scan) directory made by this tool or another system's images and robot pose files.

Results go to OUT/results/: calibration.yaml (what `scan` and `reconstruct` read with
--calibration), report.json and report.txt.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from reconstruction.calibration.board_reasons import detect_board_or_reason, larger_chessboard
from reconstruction.calibration.boards import BoardSpec, Detection
from reconstruction.calibration.depth_scale import depth_scale_fit
from reconstruction.calibration.file import load_calibration
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.plausibility import implausible_figures, rank_conventions
from reconstruction.calibration.pose_files import (
    POSE_PRESETS,
    PoseFormat,
    read_pose_file,
    read_pose_list,
)
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import RefusedResultError, ScannerError
from reconstruction.common.yaml_files import read_yaml
from reconstruction.depth.camera_model import RgbdCamera
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera, stereo_camera_from_dict
from robots.sensors.registry import sensor_of_camera_file
from robots.simulation.truth import load_truth
from scanner.calibrate.cameras_only import CamerasRun, calibrate_cameras, require_board_size
from scanner.calibrate.corners import ImageLoader, rank_pictures
from scanner.calibrate.report import CALIBRATION_FILE, build_report, truth_errors, write_results
from scanner.calibrate.solve import CalibrationRun, Solution, solve
from scanner.configs.typed_yaml import from_dict
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.results_folder import free_results_dir, require_replaceable

IMAGE_SUFFIXES = (".png", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff")


def _natural_key(path: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def _read_gray(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ScannerError(f"{path}: missing or unreadable image")
    return image


def _detect(
    board: BoardSpec, image: np.ndarray, settings: CalibrationSettings
) -> tuple[Detection | None, str]:
    """The detection, or None and the reason it failed."""
    found = detect_board_or_reason(board, image, settings.min_points_per_view)
    return (None, found) if isinstance(found, str) else (found, "")


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
    # The arm that made the poses, as a configuration's `robot` (None: the one a calibration
    # directory records, else the RX60).
    robot: str | None = None


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


def _images(root: Path) -> list[Path]:
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
    return images


def cameras_only_images(root: Path, options: OfflineOptions) -> list[Path] | None:
    """The images of a foreign folder that has no robot poses at all (no --pose-file, no pose
    file beside any image): a camera-only calibration. None when there are poses."""
    root = Path(root)
    if not root.is_dir() or (root / "scan.yaml").is_file() or options.pose_file is not None:
        return None
    images = _images(root)
    if any((root / (image.stem + options.pose_suffix)).is_file() for image in images):
        return None
    return images


def calibrate_cameras_directory(
    root: Path,
    options: OfflineOptions,
    settings: CalibrationSettings,
    out_dir: Path,
    force: bool = False,
) -> CamerasRun:
    """The cameras alone from a folder without robot poses (see `cameras_only`)."""
    images = cameras_only_images(root, options)
    if images is None:
        raise ScannerError(f"{root}: has robot poses; calibrate it with hand-eye")
    if options.board is None:
        raise ScannerError(f"{root}: give the board (--board, --board-size, --board-spacing)")
    if options.intrinsics is not None:
        raise ScannerError("--intrinsics: a camera-only calibration estimates them; leave it out")
    return calibrate_cameras(
        root, images, options.board, settings, out_dir, force, _read_gray, _detect
    )


def _read_poses(
    root: Path, images: list[Path], options: OfflineOptions, fmt: PoseFormat
) -> list[np.ndarray]:
    """X_WF of every image, from the pose list or one pose file per image."""
    if options.pose_file is not None:
        poses = read_pose_list(options.pose_file, fmt)
        if len(poses) != len(images):
            raise ScannerError(
                f"{options.pose_file}: {len(poses)} poses for {len(images)} images; one pose per "
                "image, in the images' name order"
            )
        return poses
    poses = []
    for image in images:
        pose_path = root / (image.stem + options.pose_suffix)
        if not pose_path.is_file():
            raise ScannerError(
                f"{pose_path}: missing pose file for {image.name} (or give --pose-file)"
            )
        poses.append(read_pose_file(pose_path, fmt))
    return poses


def _foreign_observations(
    root: Path, options: OfflineOptions, settings: CalibrationSettings
) -> tuple[list[PoseObservation], tuple[int, int]]:
    """Images (and left/ right/ subfolders for a stereo pair) with their robot poses."""
    stereo = (root / "left").is_dir() and (root / "right").is_dir()
    images = _images(root)
    if options.board is None:
        raise ScannerError(f"{root}: give the board (--board, --board-size, --board-spacing)")
    poses = _read_poses(root, images, options, options.pose_format)
    observations, size, larger = [], None, []
    for image, X_WF in zip(images, poses):
        gray = _read_gray(image)
        this_size = (gray.shape[1], gray.shape[0])
        if size is not None and this_size != size:
            raise ScannerError(f"{image}: image size {this_size} differs from the first {size}")
        size = this_size
        right = None
        if stereo:
            right_path = root / "right" / image.name
            right, _ = _detect(options.board, _read_gray(right_path), settings)
        left, why = _detect(options.board, gray, settings)
        if left is not None:
            larger.append(larger_chessboard(options.board, gray))
        observations.append(PoseObservation(image.stem, X_WF, left, right, why))
    require_board_size(root, options.board, larger)
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
        left, why = _detect(board, capture.left, settings)
        right = None if capture.right is None else _detect(board, capture.right, settings)[0]
        observations.append(
            PoseObservation(f"{index:04d}", capture.X_WF, left, right, why, capture.q_rad)
        )
    return observations, size


def _convention_hint(
    root: Path, options: OfflineOptions, solution: Solution, settings: CalibrationSettings
) -> str:
    """Which pose preset (direct or inverse) the board views fit best, as advice; a preset is
    suggested only when OpenCV's hand-eye under it keeps the board within the scatter limit."""
    images = _images(root)
    names = [image.stem for image in images]
    X_CB = solution.hand_eye.X_CB
    used = [k for k, name in enumerate(names) if name in X_CB]
    poses = {}
    for preset, fmt in POSE_PRESETS.items():
        for inverse in (False, True):
            try:
                X_WF = _read_poses(root, images, options, replace(fmt, inverse=inverse))
            except ScannerError:
                continue  # these files do not have this layout
            poses[preset + (" with --inverse-poses" if inverse else "")] = [X_WF[k] for k in used]
    ranked = rank_conventions(poses, [X_CB[names[k]] for k in used])
    if not ranked or ranked[0][1] > settings.max_board_scatter_m:
        return "; no pose preset fits these images either"
    name, scatter = ranked[0]
    return (
        f"; the poses fit --pose-convention {name} best, without other pose options (board "
        f"scatter {1e3 * scatter:.1f} mm under OpenCV's hand-eye)"
    )


def _options_used(board: BoardSpec, options: OfflineOptions, is_store: bool) -> dict:
    """What the solve assumed, as the flags that set it (for the report)."""
    spec = f"{board.kind} {board.cols}x{board.rows} squares of {board.spacing_m:g} m"
    used = {"--board": spec + (", inverted" if board.inverted else "")}
    if not is_store:
        fmt = options.pose_format
        used["poses"] = (
            f"{fmt.layout}, {fmt.length_unit}/{fmt.angle_unit}"
            + (f", euler {fmt.euler}" if fmt.layout in ("xyz_euler", "euler_xyz") else "")
            + (", inverse" if fmt.inverse else "")
        )
        if options.pose_file is not None:
            used["--pose-file"] = str(options.pose_file)
    if options.intrinsics is not None:
        used["--intrinsics"] = str(options.intrinsics)
    return used


def _store_images(store: CaptureStore) -> ImageLoader:
    def load(name: str, side: str) -> np.ndarray:
        return getattr(store.read_capture(int(name)), side)

    return load


def _folder_images(root: Path) -> ImageLoader:
    paths = {p.stem: p for p in _images(root)}

    def load(name: str, side: str) -> np.ndarray:
        path = paths[name]
        return _read_gray(path if side == "left" else root / "right" / path.name)

    return load


def _truth_of(root: Path) -> tuple[np.ndarray, StereoCamera, np.ndarray] | None:
    path = root / "truth.yaml"
    if not path.is_file():
        return None

    truth, _ = load_truth(path)
    return truth.X_FC, truth.stereo, truth.joint_offsets_rad


def _with_depth_correction(
    store: CaptureStore, board: BoardSpec, solution: Solution, device: RgbdCamera
):
    """An RGB-D calibration's depth-scale correction from the board's plane in the depth
    images (at the calibrated colour camera's board poses), into the calibration."""
    found = [o for o in solution.observations if o.left is not None]
    depths = [store.read_capture(int(o.name)).depth for o in found]
    fit = depth_scale_fit(
        board, [o.left for o in found], depths, solution.calibration.camera, device
    )
    calibration = replace(solution.calibration, depth_correction=fit.correction)
    return replace(solution, calibration=calibration), {
        "depth_correction": fit.correction,
        "depth_correction_spread": fit.spread,
        "depth_correction_poses": fit.poses,
        "depth_correction_pixels": fit.pixels,
    }


def calibrate_directory(
    root: Path,
    options: OfflineOptions = OfflineOptions(),
    settings: CalibrationSettings = CalibrationSettings(),
    out_dir: Path | None = None,
    extra_report: dict | None = None,
    force: bool = False,
) -> CalibrationRun:
    """Calibrate from a directory: this tool's calibration directory, or another system's
    images + poses. Results go to out_dir/results, which must not hold a calibration unless
    `force`; without out_dir, a calibration directory gets the first of root/results,
    root/results-2, ... that holds none (another system's folder is never modified)."""
    root = Path(root)
    if not root.is_dir():
        raise ScannerError(f"{root}: no such directory")
    intrinsics = None if options.intrinsics is None else load_intrinsics(options.intrinsics)
    is_store = (root / "scan.yaml").is_file()
    if is_store:
        store = CaptureStore.open(root)
        manifest = store.read_manifest()
        board = options.board
        if board is None:
            if "board" not in manifest:
                raise ScannerError(f"{store.manifest_path}: no board recorded; give --board")
            board = from_dict(BoardSpec, manifest["board"], f"{store.manifest_path}:board")
        observations, size = _store_observations(store, board, settings)
        source = "simulation" if (root / "truth.yaml").is_file() else f"offline:{root}"
    else:
        observations, size = _foreign_observations(root, options, settings)
        board = options.board
        source = f"offline:{root}"
        if out_dir is None:
            raise ScannerError("offline calibration of another system's folder needs --out DIR")
    if out_dir is None:
        out_dir, results_dir = root, free_results_dir(root, CALIBRATION_FILE)
    else:
        results_dir = Path(out_dir) / "results"
        require_replaceable(results_dir, CALIBRATION_FILE, force, "calibration")
    if isinstance(intrinsics, PinholeCamera) and intrinsics.width == 1:
        intrinsics = _with_size(intrinsics, size)
    # The run's recorded camera model says which sensor took the captures.
    device = sensor = None
    if is_store and "camera" in manifest:
        sensor = sensor_of_camera_file(manifest["camera"])
        device = sensor.model_from_dict(manifest["camera"], f"{store.manifest_path}:camera")
    if sensor is not None and intrinsics is None:
        # A device's factory intrinsics where the sensor keeps them (the model the run
        # recorded), else solved from the board.
        intrinsics = sensor.board_intrinsics(device)
    robot = options.robot or (manifest.get("robot") if is_store else None) or "rx60"
    solution = solve(board, observations, size, settings, intrinsics, source, robot)
    problems = implausible_figures(solution.hand_eye, settings, solution.calibration.stereo)
    if problems:
        hint = "" if is_store else _convention_hint(root, options, solution, settings)
        raise RefusedResultError(
            f"calibration refused, nothing written: {'; '.join(problems)}. Likely causes: the "
            "robot pose convention (Euler order, units, inverse poses) or the board "
            f"description{hint}"
        )
    depth_report = {}
    if sensor is not None and sensor.solves_depth_scale:
        solution, depth_report = _with_depth_correction(store, board, solution, device)
    truth = _truth_of(root)
    errors = None if truth is None else truth_errors(solution, *truth)
    if errors is not None and depth_report:
        e = load_truth(root / "truth.yaml")[0].depth_scale_error
        errors["depth_correction_error"] = depth_report["depth_correction"] - (1 + e)
    pictures = rank_pictures(board, solution)
    extra = {
        "corner_pictures": [p.file_name for p in pictures],
        **depth_report,
        **(extra_report or {}),
    }
    extra["options"] = {
        **_options_used(board, options, is_store),
        **(extra_report or {}).get("options", {}),
    }
    report = build_report(solution, errors, extra)
    load = _store_images(store) if is_store else _folder_images(root)
    path = write_results(results_dir, solution, report, pictures, load)
    return CalibrationRun(Path(out_dir), results_dir, path, report, solution)

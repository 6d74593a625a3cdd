"""`scanner calibrate`: stereo + hand-eye calibration (simulated or offline) and eye-to-hand.

Three entry points, one solver (reconstruction.calibration):
- `run_eye_in_hand` (scanner.calibrate_sim): a board on a stand in the simulated cell (or the
  real one, through `driver`); the arm
  visits K stations chosen for conditioning (scanner.calibration_stations), each stereo pair and
  the joint positions go to a calibration directory (the scans' crash-safe CaptureStore), then
  `calibrate_directory`.
- `calibrate_directory`: calibrate from recorded data: a calibration/scan directory made by this
  tool, or a folder of images and robot pose files made by another system (`OfflineOptions`).
- `run_eye_to_hand` (scanner.calibrate_eye_to_hand): a static stereo camera and a blinking
  marker on the flange (KTH report).

Outputs in OUT/results/: calibration.yaml (reconstruction.calibration_file; what `scan` and
`reconstruct` read with --calibration), report.json (SI units) and report.txt (mm and degrees,
for people).
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from planners.planner import PlannerConfig
from reconstruction.boards import BoardSpec, detect_board
from reconstruction.calibration import (
    CalibrationSettings,
    HandEyeCalibration,
    PoseObservation,
    StereoCalibration,
    calibrate_camera,
    calibrate_hand_eye,
    calibrate_stereo,
    require_poses,
)
from reconstruction.calibration_file import Calibration, load_calibration, save_calibration
from reconstruction.camera_model import (
    PinholeCamera,
    StereoCamera,
    stereo_camera_from_dict,
)
from reconstruction.errors import ScannerError
from reconstruction.eye_to_hand import (
    MarkerDetectionSettings,
)
from reconstruction.pose_files import PoseFormat, read_pose_file, read_pose_list
from reconstruction.rigid import pose_error
from reconstruction.yaml_files import read_yaml
from robots.blinking_marker import MarkerConfig
from robots.calibration_board import (
    BoardPlacement,
)
from robots.static_camera import StaticCameraConfig
from robots.truth import ErrorModel, load_truth
from robots.workcell import WorkcellConfig
from scanner.calibration_stations import StationConfig
from scanner.captures import CaptureStore, atomic_write_text
from scanner.config import CameraConfig
from scanner.typed_yaml import from_dict, load_yaml_file, to_dict

IMAGE_SUFFIXES = (".png", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff")
CALIBRATION_FILE = "calibration.yaml"

# Moves the arm to a configuration; False when it could not (the station is skipped).
MoveFn = Callable[[np.ndarray], bool]


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
def _default_board() -> BoardSpec:
    # 10 x 7 squares of 20 mm: one count even, one odd, so the board's orientation is unique;
    # 200 x 140 mm fits both images at 0.35 m. A plain chessboard, not ChArUco: OpenCV's
    # findChessboardCornersSB is unbiased to ~0.02 px on the renders, while ChArUco corners go
    # through cornerSubPix, which is biased by up to ~0.2 px when edges align with pixel rows.
    return BoardSpec(kind="chessboard", cols=10, rows=7, spacing_m=0.02)


@dataclass(frozen=True)
class EyeToHandConfig:
    """Static camera, flange marker, the 3D grid the marker visits and the held-out test.

    grid_*: box centre and full size (m) and spacing (m) of the calibration grid (KTH: 8, 27
    and 125 points). held_out: random points in the same box for the evaluation (KTH: 200).
    frames: images per point for temporal summation (KTH: 20). max_residual_m: the iterative
    rejection drops points farther than this from the fit.
    """

    camera: StaticCameraConfig = field(default_factory=StaticCameraConfig)
    marker: MarkerConfig = field(default_factory=MarkerConfig)
    grid_center_m: tuple[float, float, float] = (0.50, 0.05, 0.50)
    grid_size_m: tuple[float, float, float] = (0.2, 0.3, 0.2)
    grid_spacing_m: float = 0.1
    held_out: int = 100
    frames: int = 20
    detection: MarkerDetectionSettings = field(default_factory=MarkerDetectionSettings)
    max_residual_m: float = 0.003
    seed: int = 0

    def __post_init__(self) -> None:
        if self.frames < 2:
            raise ScannerError("eye_to_hand.frames: frame differencing needs at least 2 frames")
        if self.held_out < 0:
            raise ScannerError("eye_to_hand.held_out: must be >= 0")
        if any(s < 0 for s in self.grid_size_m):
            raise ScannerError("eye_to_hand.grid_size_m: sizes must be >= 0")


@dataclass(frozen=True)
class CalibrateConfig:
    """Everything `scanner calibrate` uses; every section has defaults (YAML: --config FILE)."""

    board: BoardSpec = field(default_factory=_default_board)
    placement: BoardPlacement = field(default_factory=BoardPlacement)
    stations: StationConfig = field(default_factory=StationConfig)
    solver: CalibrationSettings = field(default_factory=CalibrationSettings)
    camera: CameraConfig = field(default_factory=CameraConfig)
    cell: WorkcellConfig = field(default_factory=WorkcellConfig)
    error_model: ErrorModel = field(default_factory=ErrorModel)
    eye_to_hand: EyeToHandConfig = field(default_factory=EyeToHandConfig)
    # Stations are in open space in front of the robot: a smaller roadmap than a scan's does.
    planner: PlannerConfig = field(default_factory=lambda: PlannerConfig(roadmap_milestones=400))
    # Real hardware for eye-in-hand runs: 'package.module:factory' (see robots.drivers.Hardware);
    # the board then stands where `placement` says. None: the Drake simulation.
    driver: str | None = None


def load_calibrate_config(path: Path | None) -> CalibrateConfig:
    return CalibrateConfig() if path is None else load_yaml_file(CalibrateConfig, path)


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Solution:
    """What one calibration produced (before it is written)."""

    calibration: Calibration
    hand_eye: HandEyeCalibration
    stereo: StereoCalibration | None
    camera_rms_px: float | None  # mono: calibrateCamera RMS; None when intrinsics were given
    observations: tuple[PoseObservation, ...]
    solve_s: float


@dataclass(frozen=True, eq=False)
class CalibrationRun:
    out_dir: Path
    calibration_file: Path
    report: dict
    solution: Solution


# --------------------------------------------------------------------------------------------
# The solver on observations
# --------------------------------------------------------------------------------------------
def solve(
    board: BoardSpec,
    observations: list[PoseObservation],
    image_size: tuple[int, int],
    settings: CalibrationSettings,
    intrinsics: StereoCamera | PinholeCamera | None = None,
    source: str = "offline",
) -> Solution:
    """Intrinsics (unless given), then hand-eye; stereo when any pose has a right image."""
    t0 = time.perf_counter()
    is_stereo = any(o.right is not None for o in observations)
    found = [o for o in observations if o.left is not None]
    missing = [o.name for o in observations if o.left is None]
    require_poses(len(found), len(observations), missing, settings.min_poses)
    stereo_cal, camera_rms = None, None
    if intrinsics is None:
        if is_stereo:
            stereo_cal = calibrate_stereo(board, observations, image_size, settings)
            cameras: StereoCamera | PinholeCamera = stereo_cal.stereo
        else:
            mono = calibrate_camera(board, [o.left for o in found], image_size, settings)
            cameras, camera_rms = mono.camera, mono.rms_px
    else:
        if is_stereo and not isinstance(intrinsics, StereoCamera):
            raise ScannerError("stereo data needs stereo intrinsics (a stereo camera file)")
        cameras = intrinsics
        if not is_stereo and isinstance(intrinsics, StereoCamera):
            cameras = intrinsics.left
        size = cameras.left if isinstance(cameras, StereoCamera) else cameras
        if (size.width, size.height) != tuple(image_size):
            raise ScannerError(
                f"the intrinsics are for {size.width}x{size.height} images, the images are "
                f"{image_size[0]}x{image_size[1]}"
            )
    hand_eye = calibrate_hand_eye(board, observations, cameras, settings)
    quality = {
        "reprojection_rms_px": hand_eye.rms_px,
        "reprojection_rms_after_robot_corrections_px": hand_eye.corrected_rms_px,
        "stereo_rms_px": None if stereo_cal is None else stereo_cal.rms_px,
        "poses_used": len(hand_eye.used),
        "poses_outliers": hand_eye.outliers,
        "poses_board_not_found": hand_eye.not_found,
        "board_scatter_m": hand_eye.board_scatter_m.tolist(),
        "hand_eye_seed": hand_eye.seed_method,
    }
    calibration = Calibration(
        hand_eye.X_FC,
        cameras if isinstance(cameras, StereoCamera) else None,
        cameras.left if isinstance(cameras, StereoCamera) else cameras,
        source,
        "",
        hand_eye.X_WB,
        to_dict(board),
        quality,
    )
    return Solution(
        calibration,
        hand_eye,
        stereo_cal,
        camera_rms,
        tuple(observations),
        time.perf_counter() - t0,
    )


# --------------------------------------------------------------------------------------------
# Reading recorded data
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# Reports
# --------------------------------------------------------------------------------------------
def truth_errors(solution: Solution, truth_X_FC: np.ndarray, truth_stereo: StereoCamera) -> dict:
    """Errors against the simulator's truth (SI units): ours and each OpenCV method alone."""
    dt, dr = pose_error(solution.hand_eye.X_FC, truth_X_FC)
    out = {"handeye_error_m": dt, "handeye_error_rad": dr, "opencv": {}}
    for name, X in solution.hand_eye.opencv.items():
        mt, mr = pose_error(X, truth_X_FC)
        out["opencv"][name] = {"handeye_error_m": mt, "handeye_error_rad": mr}
    cams = solution.calibration.stereo
    if cams is not None:
        out["focal_error_px"] = [
            float(np.abs(np.diag(c.K)[:2] - np.diag(t.K)[:2]).max())
            for c, t in ((cams.left, truth_stereo.left), (cams.right, truth_stereo.right))
        ]
        out["principal_point_error_px"] = [
            float(np.linalg.norm(c.K[:2, 2] - t.K[:2, 2]))
            for c, t in ((cams.left, truth_stereo.left), (cams.right, truth_stereo.right))
        ]
        out["baseline_error_m"] = abs(cams.baseline_m - truth_stereo.baseline_m)
    return out


def build_report(solution: Solution, truth: dict | None, extra: dict | None = None) -> dict:
    he = solution.hand_eye
    per_pose = []
    for r in he.residuals:
        xi = he.robot_corrections.get(r.name)
        per_pose.append(
            {
                "name": r.name,
                "status": r.status,
                "rms_px": None if math.isnan(r.rms_px) else r.rms_px,
                "robot_correction_m": None if xi is None else float(np.linalg.norm(xi[3:])),
                "robot_correction_rad": None if xi is None else float(np.linalg.norm(xi[:3])),
            }
        )
    report = {
        "source": solution.calibration.source,
        "poses": len(he.residuals),
        "poses_used": len(he.used),
        "poses_outliers": he.outliers,
        "poses_board_not_found": he.not_found,
        "reprojection_rms_px": he.rms_px,
        "reprojection_rms_after_robot_corrections_px": he.corrected_rms_px,
        "stereo_rms_px": None if solution.stereo is None else solution.stereo.rms_px,
        "camera_rms_px": solution.camera_rms_px,
        "per_pose": per_pose,
        "board_scatter_m": he.board_scatter_m.tolist(),
        "board_scatter_max_m": he.board_scatter_max_m,
        "motion": {
            "max_rotation_rad": he.motion.max_rotation_rad,
            "axis_spread_rad": he.motion.axis_spread_rad,
        },
        "hand_eye_seed": he.seed_method,
        "opencv_failed": he.opencv_failed,
        "X_FC": he.X_FC.tolist(),
        "X_FC_opencv": {k: v.tolist() for k, v in he.opencv.items()},
        "X_WB": he.X_WB.tolist(),
        "solve_s": solution.solve_s,
    }
    if truth is not None:
        report["truth"] = truth
    report.update(extra or {})
    return report


def report_text(report: dict) -> str:
    """The report for people: millimetres and degrees (the files hold metres and radians)."""
    mm, deg = 1000.0, 180.0 / math.pi
    lines = [
        f"calibration from {report['source']} (printed in mm and degrees)",
        f"poses: {report['poses_used']} used of {report['poses']}",
    ]
    if report["poses_outliers"]:
        lines.append(f"  rejected as outliers: {', '.join(report['poses_outliers'])}")
    if report["poses_board_not_found"]:
        lines.append(f"  board not found in: {', '.join(report['poses_board_not_found'])}")
    if report.get("stereo_rms_px") is not None:
        lines.append(f"stereo calibration RMS: {report['stereo_rms_px']:.3f} px")
    if report.get("camera_rms_px") is not None:
        lines.append(f"camera calibration RMS: {report['camera_rms_px']:.3f} px")
    lines.append(
        f"hand-eye reprojection RMS: {report['reprojection_rms_px']:.3f} px with the robot poses "
        f"as reported, {report['reprojection_rms_after_robot_corrections_px']:.3f} px after "
        "the small robot-pose corrections"
    )
    s = np.array(report["board_scatter_m"]) * mm
    lines.append(
        f"board-in-base scatter (std x y z): {s[0]:.2f} {s[1]:.2f} {s[2]:.2f} mm, "
        f"max {report['board_scatter_max_m'] * mm:.2f} mm"
    )
    X = np.array(report["X_FC"])
    rv = cv2.Rodrigues(X[:3, :3])[0].ravel()
    lines.append(
        f"X_FC: t = ({', '.join(f'{v * mm:.2f}' for v in X[:3, 3])}) mm, rotation vector = "
        f"({', '.join(f'{v * deg:.3f}' for v in rv)}) deg; seed method {report['hand_eye_seed']}"
    )
    lines.append("per pose (RMS px, robot correction mm / deg):")
    for p in report["per_pose"]:
        rms = "   -  " if p["rms_px"] is None else f"{p['rms_px']:6.3f}"
        corr = ""
        if p["robot_correction_m"] is not None:
            corr = (
                f"  {p['robot_correction_m'] * mm:.3f} mm / "
                f"{p['robot_correction_rad'] * deg:.4f} deg"
            )
        lines.append(f"  {p['name']:>12}  {rms}  {p['status']}{corr}")
    truth = report.get("truth")
    if truth:
        lines.append(
            f"against the simulator's truth: hand-eye {truth['handeye_error_m'] * mm:.3f} mm, "
            f"{truth['handeye_error_rad'] * deg:.4f} deg"
        )
        for name, e in truth["opencv"].items():
            lines.append(
                f"  OpenCV {name:<10} alone: {e['handeye_error_m'] * mm:.3f} mm, "
                f"{e['handeye_error_rad'] * deg:.4f} deg"
            )
        if "focal_error_px" in truth:
            lines.append(
                f"  focal length error {max(truth['focal_error_px']):.3f} px, principal point "
                f"{max(truth['principal_point_error_px']):.3f} px, baseline "
                f"{truth['baseline_error_m'] * mm:.3f} mm"
            )
    return "\n".join(lines) + "\n"


def write_results(out_dir: Path, solution: Solution, report: dict) -> Path:
    results = Path(out_dir) / "results"
    results.mkdir(parents=True, exist_ok=True)
    path = save_calibration(solution.calibration, results / CALIBRATION_FILE)
    atomic_write_text(results / "report.json", json.dumps(report, indent=2) + "\n")
    atomic_write_text(results / "report.txt", report_text(report))
    return path


# --------------------------------------------------------------------------------------------
# Offline calibration (recorded data)
# --------------------------------------------------------------------------------------------
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

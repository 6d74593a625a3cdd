"""What `scanner calibrate` uses (YAML: --config FILE): board, its placement, stations, solver,
camera, cell, error model, eye-to-hand set-up and planner; every section has defaults."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from planners.config import PlannerConfig
from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.eye_to_hand import MarkerDetectionSettings
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml
from reconstruction.depth.camera_model import DepthDesign
from reconstruction.stereo.camera_model import StereoDesign
from robots.drivers.settings import HardwareConfig
from robots.models.calibration_board import BoardPlacement
from robots.models.workcell import WorkcellConfig
from robots.sensors import sensor_named
from robots.simulation.blinking_marker import MarkerConfig
from robots.simulation.static_camera import StaticCameraConfig
from robots.simulation.truth import MAX_SEED, ErrorModel
from scanner.calibrate.stations import StationConfig
from scanner.configs.references import check_driver, check_robot, resolve_relative_paths
from scanner.configs.typed_yaml import from_dict


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
    grid_spacing_m: float = positive(0.1, at_most=1.0)
    held_out: int = integer(100, minimum=0, maximum=10_000)
    frames: int = 20
    detection: MarkerDetectionSettings = field(default_factory=MarkerDetectionSettings)
    max_residual_m: float = positive(0.003)
    seed: int = integer(0, minimum=0, maximum=MAX_SEED)

    def __post_init__(self) -> None:
        if self.frames < 2:
            raise ScannerError("eye_to_hand.frames: frame differencing needs at least 2 frames")
        check_fields("eye_to_hand", self)
        if any(s < 0 for s in self.grid_size_m):
            raise ScannerError("eye_to_hand.grid_size_m: sizes must be >= 0")


@dataclass(frozen=True)
class CalibrateConfig:
    """Everything `scanner calibrate` uses; every section has defaults (YAML: --config FILE)."""

    board: BoardSpec = field(default_factory=_default_board)
    # The arm, as in a scan configuration: "rx60" or the path of an arm file.
    robot: str = "rx60"
    placement: BoardPlacement = field(default_factory=BoardPlacement)
    stations: StationConfig = field(default_factory=StationConfig)
    solver: CalibrationSettings = field(default_factory=CalibrationSettings)
    camera: StereoDesign = field(default_factory=StereoDesign)
    cell: WorkcellConfig = field(default_factory=WorkcellConfig)
    error_model: ErrorModel = field(default_factory=ErrorModel)
    eye_to_hand: EyeToHandConfig = field(default_factory=EyeToHandConfig)
    # Stations are in open space in front of the robot: a smaller roadmap than a scan's does.
    planner: PlannerConfig = field(default_factory=lambda: PlannerConfig(roadmap_milestones=400))
    # Real hardware for eye-in-hand runs: 'package.module:factory' (see
    # robots.drivers.interfaces.Hardware);
    # the board then stands where `placement` says. None: the Drake simulation.
    driver: str | None = None
    # Or a real cell from configuration (robot link, camera), as in a scan configuration; the
    # camera kind "simulated" renders the simulated board cell at the joints the link reports.
    hardware: HardwareConfig | None = None
    # What the tool carries: "stereo" (camera:) or "rgbd" (rgbd:, a depth camera whose colour
    # images find the board; its depth then gives a depth-scale correction).
    sensor: str = "stereo"
    rgbd: DepthDesign = field(default_factory=DepthDesign)

    def __post_init__(self) -> None:
        sensor_named(self.sensor, scanning=True)
        if not isinstance(self.robot, str) or not self.robot.strip():
            raise ScannerError(
                f"robot: expected 'rx60' or the path of an arm file, got {self.robot!r}"
            )
        if self.driver and self.hardware is not None:
            raise ScannerError(
                "hardware: a calibration runs on --driver MODULE:FACTORY or on a hardware: "
                "section, not both"
            )


def load_calibrate_config(path: Path | None) -> CalibrateConfig:
    """The calibration configuration file `path` (None: the defaults), its relative paths read
    from its folder and its driver imported now; errors name the file and the key."""
    if path is None:
        return CalibrateConfig()
    data = resolve_relative_paths(read_yaml(path, "configuration") or {}, Path(path).parent)
    config = from_dict(CalibrateConfig, data, str(path))
    check_robot(config.robot, f"{path}: robot")
    if config.driver:
        check_driver(config.driver, f"{path}: driver")
    return config

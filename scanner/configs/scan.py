"""The scan configuration: one typed, validated record loaded from YAML (`--config FILE`).

Every section has defaults, so an empty file (or none) is a valid configuration; unknown keys
are rejected with the list of valid ones. Units are in the field names.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from planners.config import PlannerConfig
from reconstruction.common.checks import check_fields, fraction, integer, non_negative, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml
from reconstruction.config import ReconstructionConfig
from reconstruction.depth.camera_model import DepthDesign
from reconstruction.stereo.camera_model import StereoDesign
from reconstruction.stereo.params import StereoParams
from reconstruction.surfaces.export import MeshExportConfig
from reconstruction.surfaces.meshes import MESH_SUFFIXES
from robots.drivers.settings import HardwareConfig
from robots.models.workcell import WorkcellConfig
from robots.sensors import sensor_named
from robots.simulation.truth import ErrorModel
from scanner.configs.flags import for_flag
from scanner.configs.references import (
    absolute_arm_file,
    check_calibration_file,
    check_driver,
    check_object,
    check_references,
    check_robot,
    resolve_relative_paths,
)
from scanner.configs.typed_yaml import from_dict, to_dict
from scanner.configs.views import ViewpointConfig
from scanner.monitor.cell_monitor import MonitorSettings


@dataclass(frozen=True)
class MachineConfig:
    """Decision-maker retries and settling: the arm counts as at rest when every joint is
    within settle_tolerance_rad of the goal, polled until settle_timeout_s."""

    capture_retries: int = integer(2, minimum=0)
    settle_tolerance_rad: float = positive(1e-3)
    settle_timeout_s: float = positive(5.0)

    def __post_init__(self) -> None:
        check_fields("machine", self)


@dataclass(frozen=True)
class ProcessingConfig:
    """How captures become a model (`processing:` in a scan config, or `--config` offline)."""

    stereo: StereoParams = field(default_factory=StereoParams)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    # Points closer than this to the robot, tool, rod or cell primitives are removed.
    remove_margin_m: float = non_negative(0.01)
    # On a table or turntable, points less than this above its top (in each pass's own frame)
    # are removed: the top, its leg, the cell's table under it, and the stereo's wrong matches
    # on their plain faces, which land centimetres off them (beyond remove_margin_m) but below
    # the top. Small: the object's lowest millimetres go with them (other passes show them).
    support_margin_m: float = non_negative(0.003)
    # The surface whose metrics are the report's headline keys.
    primary_surface: str = "poisson"
    mesh_formats: tuple[str, ...] = (".ply",)
    # Unit, frame and decimation of the mesh files (--units, --frame, --decimate).
    mesh_export: MeshExportConfig = field(default_factory=MeshExportConfig)
    # Surface samples for the metrics (area-uniform on the truth and on each result).
    metric_samples: int = integer(200_000, minimum=1000)
    # Deviation pictures: the colour scale's end (+-), fixed so that runs compare by eye, and
    # the tolerance band the statistics count within.
    deviation_scale_m: float = positive(0.001)
    deviation_tolerance_m: float = positive(0.0005)

    def __post_init__(self) -> None:
        bad = [f for f in self.mesh_formats if f not in MESH_SUFFIXES]
        if bad:
            raise ScannerError(
                f"processing.mesh_formats: {', '.join(map(repr, bad))} not known; expected "
                f"suffixes from {', '.join(MESH_SUFFIXES)}"
            )
        check_fields("processing", self)
        built = self.reconstruction.surfaces.methods
        if self.primary_surface not in built:
            raise ScannerError(
                f"processing.primary_surface: expected one of the surfaces built "
                f"(processing.reconstruction.surfaces.methods: {', '.join(built)}), got "
                f"{self.primary_surface!r}"
            )


MAX_HANGINGS = 6
AUTO = "auto"
# How the object is offered and turned between passes (scanner/scan/presentation/).
PRESENTATIONS = ("hanging", "turntable", "table")


@dataclass(frozen=True)
class ScanConfig:
    object: str = "vase"
    # The arm: "rx60" (the Staubli RX60, closed-form kinematics) or the path of an arm file
    # (robots/arms/arm_file.py; e.g. scanner/configs/arms/ur5e.yaml).
    robot: str = "rx60"
    cell: WorkcellConfig = field(default_factory=WorkcellConfig)
    # The nominal stereo camera (what the software believes; the simulator's truth equals it
    # unless a calibration file says otherwise).
    camera: StereoDesign = field(default_factory=StereoDesign)
    # What measures depth, a sensor kind (robots.sensors): "stereo" (the pair above, SGBM),
    # "rgbd" (an active depth camera with a colour camera beside it, `rgbd:`; a RealSense
    # D415-class device by default), or a kind a plug-in registers.
    sensor: str = "stereo"
    rgbd: DepthDesign = field(default_factory=DepthDesign)
    views: ViewpointConfig = field(default_factory=ViewpointConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    error_model: ErrorModel = field(default_factory=ErrorModel)
    machine: MachineConfig = field(default_factory=MachineConfig)
    # A `scanner calibrate` result (stereo model + X_FC) the software uses instead of the
    # nominal ones; in simulation the true camera and mount stay those of the error model.
    calibration_file: str | None = None
    processing: ProcessingConfig = field(default_factory=ProcessingConfig)
    # Reconstruct at the end of the scan (off: capture only; `scanner reconstruct` later).
    reconstruct: bool = True
    # Real hardware instead of the simulator: 'package.module:factory', factory(config) ->
    # robots.drivers.interfaces.Hardware (robot + stereo camera drivers). None: the Drake
    # simulation.
    driver: str | None = None
    # A real cell from configuration (robot link and camera kinds, hosts, ports, devices);
    # exclusive with `driver`. None: the Drake simulation.
    hardware: HardwareConfig | None = None
    # Passes over the object, re-hung (turned) between them; the passes are aligned and merged
    # into one model. One hanging never sees the top of a hung object. "auto": after each
    # hanging the scanner estimates what it has not seen and asks for another hanging, turned
    # as it computes, until `coverage_target` is reached, `max_hangings` are done, or a
    # hanging adds less than `min_hanging_gain` of the surface. A number forces that many.
    hangings: int | str = AUTO
    # How the object is presented: "hanging" (from the rod, re-hung by a person between
    # passes), "turntable" (standing on a motorised turntable the scanner turns between
    # passes; `hangings` is then its number of passes) or "table" (lying on the support
    # table, laid on another face by a person between passes). The cell must have a model.
    presentation: str = "hanging"
    coverage_target: float = fraction(0.97)
    max_hangings: int = integer(4, maximum=MAX_HANGINGS)
    min_hanging_gain: float = fraction(0.01)
    # The static-camera cell monitor (off by default): intrusions pause the scan.
    monitor: MonitorSettings = field(default_factory=MonitorSettings)

    def __post_init__(self) -> None:
        h = self.hangings
        if h != AUTO and (
            isinstance(h, bool) or not isinstance(h, int) or not 1 <= h <= MAX_HANGINGS
        ):
            raise ScannerError(
                f"hangings: expected '{AUTO}' or an integer in [1, {MAX_HANGINGS}], got {h!r}"
            )
        if not 0 < self.coverage_target <= 1:
            raise ScannerError(
                f"coverage_target: expected a fraction in (0, 1], got {self.coverage_target}"
            )
        if not isinstance(self.robot, str) or not self.robot.strip():
            raise ScannerError(
                f"robot: expected 'rx60' or the path of an arm file, got {self.robot!r}"
            )
        if self.presentation not in PRESENTATIONS:
            raise ScannerError(
                f"presentation: expected one of {', '.join(PRESENTATIONS)}, got "
                f"{self.presentation!r}"
            )
        # The kinds a scan can run with come from the registry (robots.sensors).
        sensor_named(self.sensor, scanning=True)
        if self.driver and self.hardware is not None:
            raise ScannerError(
                "hardware: a scan runs on --driver MODULE:FACTORY or on a hardware: section, "
                "not both"
            )
        check_fields("scan", self)

    @property
    def auto_hangings(self) -> bool:
        return self.hangings == AUTO

    @property
    def first_hangings(self) -> int:
        """How many hangings are planned at the start (auto: one, more when needed)."""
        return 1 if self.auto_hangings else int(self.hangings)

    @property
    def scan_center_m(self) -> tuple[float, float, float]:
        return self.views.center_m or self.cell.object_center_m


def load_scan_config(path: Path | None) -> ScanConfig:
    """The configuration file `path` (None: the defaults): its relative paths read from its
    folder, every field validated, and what it names (object, calibration file, driver) loaded
    now; errors name the file and the key."""
    if path is None:
        return ScanConfig()
    data = resolve_relative_paths(read_yaml(path, "configuration") or {}, Path(path).parent)
    config = scan_config_from_dict(data, str(path))
    check_references(config, str(path))
    return config


def scan_config_from_dict(data: dict, where: str) -> ScanConfig:
    """The configuration `data` holds. An arm file's scan whose `cell` names no
    object_center_m hangs the object where the arm reaches most of the viewpoint sphere (left
    None here, laid out by scanner.scan.layout); the RX60's keeps its measured cell."""
    config = from_dict(ScanConfig, data, where)
    cell = data.get("cell") or {}
    if config.robot != "rx60" and "object_center_m" not in cell:
        config = replace(config, cell=replace(config.cell, object_center_m=None))
    if config.robot != "rx60" and "support_top_m" not in cell:
        # The RX60's support place is not another arm's: its object stands where it hangs.
        config = replace(config, cell=replace(config.cell, support_top_m=None))
    return config


def scan_config_to_dict(config: ScanConfig) -> dict:
    return to_dict(config)


def _deep_merge(base, over):
    if isinstance(base, dict) and isinstance(over, dict):
        return {**base, **{k: _deep_merge(base.get(k), v) for k, v in over.items()}}
    return over


def resume_request(saved: ScanConfig, path: Path | None, **flags) -> ScanConfig:
    """What a resume asks for: the saved configuration with only what the user gave now (the
    keys of a --config file, the flags) applied, so that options not given are never compared."""
    config = saved
    if path is not None:
        given = resolve_relative_paths(read_yaml(path, "configuration") or {}, Path(path).parent)
        config = scan_config_from_dict(_deep_merge(scan_config_to_dict(saved), given), str(path))
    return with_overrides(config, **flags)


def with_overrides(
    config: ScanConfig,
    object_spec: str | None = None,
    size_m: float | None = None,
    views: int | None = None,
    radius_m: float | None = None,
    seed: int | None = None,
    calibration_file: str | None = None,
    driver: str | None = None,
    hangings: int | str | None = None,
    presentation: str | None = None,
    max_extra_views: int | None = None,
    monitor: bool | None = None,
    intruder_start_s: tuple[float, ...] | None = None,
    operator: str | None = None,
    sensor: str | None = None,
    robot: str | None = None,
) -> ScanConfig:
    """Command-line flags win over the file; each override is validated like the file, and
    an error names the flag."""
    if object_spec is not None:
        config = replace(config, object=object_spec)
        check_object(object_spec, config.cell.object_size_m, "--object")
    if size_m is not None:
        cell = for_flag("--size", lambda: replace(config.cell, object_size_m=size_m))
        config = replace(config, cell=cell)
    if views is not None:
        config = replace(
            config, views=for_flag("--views", lambda: replace(config.views, count=views))
        )
    if radius_m is not None:
        config = replace(
            config, views=for_flag("--radius", lambda: replace(config.views, radius_m=radius_m))
        )
    if seed is not None:
        model = for_flag("--seed", lambda: replace(config.error_model, seed=seed))
        config = replace(config, error_model=model)
    if operator is not None:
        model = for_flag("--operator", lambda: replace(config.error_model, operator=operator))
        config = replace(config, error_model=model)
    if calibration_file is not None:
        check_calibration_file(calibration_file, "--calibration")
        config = replace(config, calibration_file=calibration_file)
    if sensor is not None:
        config = for_flag("--sensor", lambda: replace(config, sensor=sensor))
    if robot is not None:
        check_robot(robot, "--robot")
        config = replace(config, robot=absolute_arm_file(robot))
        if robot != "rx60" and config.cell.object_center_m == WorkcellConfig().object_center_m:
            # The RX60's cell, not one chosen for this arm: laid out from its reach instead.
            config = replace(config, cell=replace(config.cell, object_center_m=None))
        if robot != "rx60" and config.cell.support_top_m == WorkcellConfig().support_top_m:
            config = replace(config, cell=replace(config.cell, support_top_m=None))
    if driver is not None:
        check_driver(driver, "--driver")
        config = replace(config, driver=driver)
    if max_extra_views is not None:
        views_config = for_flag(
            "--max-extra-views", lambda: replace(config.views, max_extra_views=max_extra_views)
        )
        config = replace(config, views=views_config)
    if hangings is not None:
        config = for_flag("--hangings", lambda: replace(config, hangings=hangings))
    if presentation is not None:
        config = for_flag("--presentation", lambda: replace(config, presentation=presentation))
    if monitor:
        config = replace(config, monitor=replace(config.monitor, enabled=True))
    if intruder_start_s is not None:
        settings = for_flag(
            "--intruder", lambda: replace(config.monitor, intruder_start_s=intruder_start_s)
        )
        config = replace(config, monitor=settings)
    return config

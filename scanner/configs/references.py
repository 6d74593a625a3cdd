"""What a scan configuration names outside itself: the object (a built-in name or a mesh file),
the arm (a built-in name or an arm file), the calibration file, the driver module, the roadmap
cache and the cameras' recordings.

A relative path in a configuration file is read from the file's own folder (a configuration
travels with its calibration and meshes; the working folder is wherever the user happens to
be), and what the configuration names is loaded or imported when the configuration is, so that
a bad one is refused before any work starts, naming the file and the key (or the flag).
"""

from __future__ import annotations

from pathlib import Path

from reconstruction.common.errors import ScannerError


def _relative(value) -> bool:
    return isinstance(value, str) and bool(value.strip()) and not Path(value).is_absolute()


def _is_mesh_path(spec: str) -> bool:
    from robots.models.objects import MESH_SUFFIXES

    return Path(spec).suffix.lower() in MESH_SUFFIXES


def _names_arm_file(robot: str) -> bool:
    """A YAML path, not a built-in arm (a mistyped name stays as typed in the error)."""
    from robots.arms.default import is_arm_file

    return is_arm_file(robot) and Path(robot).suffix.lower() in (".yaml", ".yml")


def _is_recording(source) -> bool:
    """A camera source that is a file or an image-sequence pattern (`rec/left_%04d.png`), not
    a device index, a device path or a URL."""
    return _relative(source) and "://" not in source and bool(Path(source).suffix)


def _moved(data: dict, key: str, folder: Path, applies) -> dict:
    value = data.get(key)
    if not applies(value):
        return data
    return {**data, key: str(folder / value)}


def resolve_relative_paths(data: dict, folder: Path) -> dict:
    """The raw mapping of a configuration file in `folder` with its relative paths made
    absolute against that folder (a copy; anything else is left to the record's checks)."""
    if not isinstance(data, dict):
        return data
    folder = Path(folder).absolute()
    data = _moved(data, "calibration_file", folder, _relative)
    data = _moved(data, "robot", folder, lambda v: _relative(v) and _names_arm_file(v))
    data = _moved(data, "object", folder, lambda v: _relative(v) and _is_mesh_path(v))
    if isinstance(data.get("planner"), dict):
        data = {**data, "planner": _moved(data["planner"], "cache_dir", folder, _relative)}
    hardware = data.get("hardware")
    if isinstance(hardware, dict) and isinstance(hardware.get("camera"), dict):
        camera = hardware["camera"]
        for side in ("left", "right"):
            camera = _moved(camera, side, folder, _is_recording)
        data = {**data, "hardware": {**hardware, "camera": camera}}
    return data


def _named(name: str, check) -> None:
    """`check()`, its ScannerError (of whatever exit code) told under `name`."""
    try:
        check()
    except ScannerError as e:
        raise type(e)(f"{name}: {e}") from None


def check_object(spec: str, size_m: float, name: str) -> None:
    """The object `spec` names exists and reads (a mesh file is read now)."""
    from robots.models.objects import BUILTIN_OBJECTS, resolve_object

    if spec not in BUILTIN_OBJECTS:
        _named(name, lambda: resolve_object(spec, size_m))


def check_calibration_file(path: str, name: str) -> None:
    """The calibration file reads, validates and is plausible (exit 3 when it is not)."""
    from reconstruction.calibration.file import load_calibration

    _named(name, lambda: load_calibration(Path(path)))


def check_driver(spec: str, name: str) -> None:
    """The driver's module imports and has the factory (not called: nothing connects)."""
    from robots.drivers.driver_module import driver_factory

    _named(name, lambda: driver_factory(spec))


def check_robot(robot: str, name: str) -> None:
    """`robot` is a built-in arm or an arm file that loads (its model parsed now)."""
    from robots.arms.default import arm_of

    _named(name, lambda: arm_of(robot))


def absolute_arm_file(robot: str) -> str:
    """A flag's arm file as an absolute path: the configuration is saved with the scan and
    read again from elsewhere (a resume, a reconstruction)."""
    from robots.arms.default import is_arm_file

    return str(Path(robot).resolve()) if is_arm_file(robot) else robot


def check_references(config, where: str) -> None:
    """Everything `config` (a ScanConfig loaded from `where`) names outside itself."""
    check_object(config.object, config.cell.object_size_m, f"{where}: object")
    check_robot(config.robot, f"{where}: robot")
    if config.calibration_file:
        check_calibration_file(config.calibration_file, f"{where}: calibration_file")
    if config.driver:
        check_driver(config.driver, f"{where}: driver")

"""Sensor kinds by name: the built-in ones and any a plug-in registers, by a call to
`register_sensor` or through the `scanner.sensors` entry point group of an installed package
(`my_depth = "my_package.sensor:MyDepth"`: a Sensor class or object)."""

from __future__ import annotations

from importlib.metadata import entry_points

from reconstruction.common.errors import ScannerError
from robots.sensors.sensor import Sensor

_SENSORS: dict[str, Sensor] = {}


def register_sensor(sensor: Sensor) -> Sensor:
    """Make `sensor` the one named `sensor.kind` (a later registration of a name replaces the
    earlier one: a test or a plug-in may refine a kind)."""
    if not isinstance(sensor, Sensor):
        raise TypeError(f"register_sensor: expected a Sensor, got {type(sensor).__name__}")
    _builtins()
    _SENSORS[sensor.kind] = sensor
    return sensor


def unregister_sensor(kind: str) -> None:
    """Forget the kind `kind` (a test's own kind, after the test)."""
    _SENSORS.pop(kind, None)


def sensor_kinds(scanning: bool = False) -> tuple[str, ...]:
    """The registered kinds, the built-in ones first; `scanning`: only those a scan or a
    calibration can run with (not `mono`, whose captures are imported)."""
    _builtins()
    return tuple(k for k, s in _SENSORS.items() if s.scans or not scanning)


def sensor_named(kind: str, field: str = "sensor", scanning: bool = False) -> Sensor:
    """The sensor of kind `kind`; an unknown kind (or, with `scanning`, one that cannot scan)
    is one line naming `field` and the known kinds."""
    known = sensor_kinds(scanning)
    if not isinstance(kind, str) or kind not in known:
        raise ScannerError(f"{field}: expected one of {', '.join(known)}, got {kind!r}")
    return _SENSORS[kind]


def open_camera_of(settings, sensor: Sensor, model):
    """The `hardware: camera:` device (`settings`, a CameraLinkConfig) opened by its sensor
    kind, after checking that the configured camera kind is one of `sensor`'s (one line
    naming hardware.camera.kind otherwise)."""
    if settings.kind not in sensor.hardware_kinds:
        owner = next((s for s in _SENSORS.values() if settings.kind in s.hardware_kinds), None)
        what = f"{owner.device_words} (sensor: {owner.kind})" if owner else "no camera"
        raise ScannerError(
            f"hardware.camera.kind: '{settings.kind}' is {what}; the configuration's sensor "
            f"is {sensor.kind}"
        )
    return sensor.open_driver(settings, model)


def sensor_of_camera_file(d) -> Sensor:
    """The kind whose camera-model file section `d` is (by its `schema`; the stereo pair's
    when it names none of theirs, whose reader then says what is wrong)."""
    _builtins()
    schema = d.get("schema") if isinstance(d, dict) else None
    return next((s for s in _SENSORS.values() if s.model_schema == schema), _SENSORS["stereo"])


ENTRY_POINTS = "scanner.sensors"


def load_entry_points(group: str = ENTRY_POINTS) -> list[str]:
    """Register the sensors installed packages declare in the entry point group `group`; the
    kinds registered."""
    kinds = []
    for point in entry_points(group=group):
        try:
            sensor = point.load()
            register_sensor(sensor() if isinstance(sensor, type) else sensor)
        except (ImportError, AttributeError, TypeError) as e:
            raise ScannerError(f"sensor plug-in {point.name} ({group}): {e}") from None
        kinds.append(point.name)
    return kinds


def _builtins() -> None:
    # Imported on first use, so that importing the registry stays cheap and a built-in
    # module may import the registry back.
    if "stereo" not in _SENSORS:
        from robots.sensors.mono import MonoSensor
        from robots.sensors.rgbd import RgbdSensor
        from robots.sensors.stereo import StereoSensor

        for sensor in (StereoSensor(), RgbdSensor(), MonoSensor()):
            _SENSORS.setdefault(sensor.kind, sensor)
        load_entry_points()

"""Sensors as plug-ins: one `Sensor` object per kind of depth sensor the tool can carry.

What differs between a stereo pair, a depth camera and an imported recording's single moving
camera lives in that kind's object (`stereo.py`, `rgbd.py`, `mono.py`): its camera model and
model file, how a capture becomes a cloud, what it can measure from a standoff, the camera a
calibration board is seen by, its simulated device and its driver. The configuration's
`sensor:` field and a scan's manifest name the kind; `registry.py` maps names to objects, and a
new kind is one module and one `register_sensor(...)` call.
"""

from robots.sensors.registry import register_sensor, sensor_kinds, sensor_named
from robots.sensors.sensor import Sensor, SensorCloud

__all__ = ["Sensor", "SensorCloud", "register_sensor", "sensor_kinds", "sensor_named"]

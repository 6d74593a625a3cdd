"""Every configuration field is validated when its file is loaded: one bad value per field,
walked from the records' dataclasses (a field added later is in the table without a line
here), each refused in one line naming the file and the field's key path."""

from __future__ import annotations

import pytest
import yaml

from reconstruction.common.errors import ScannerError
from scanner.calibrate.config import CalibrateConfig, load_calibrate_config
from scanner.configs.scan import ScanConfig, load_scan_config
from tests.config_fields import bad_value, leaf_fields, nested

# Fields whose bad value is not the one of their type: signed quantities, free text, choices
# of types, lists of records.
SCAN_OVERRIDES = {
    "cell.object_yaw_rad": float("nan"),
    "views.elevation_min_rad": 2.0,
    "views.elevation_max_rad": 2.0,
    "cell.boxes": [{"name": "box", "p_WB": [0.0, 0.0, 0.0], "size": [-0.1, 0.1, 0.1]}],
    "processing.reconstruction.icp.levels": [],
    "processing.reconstruction.handeye.refine_levels": [],
    "processing.reconstruction.handeye.coarse.levels": [],
    "processing.mesh_formats": [".xyz"],
    "object": "no-such-object",
    "calibration_file": "no-such-calibration.yaml",
    "driver": "no_such_module:connect",
    "planner.cache_dir": "",
    "hardware.robot.host": "",
    "hardware.camera.left": -1,
    "hardware.camera.right": -1,
    "hardware.camera.serial": "",
    "hangings": 0,
}

SCAN_FIELDS = leaf_fields(ScanConfig)


def test_the_table_walks_every_section():
    keys = {".".join(path) for path, _ in SCAN_FIELDS}
    assert {"object", "processing.primary_surface", "monitor.tracking.fps"} <= keys
    assert len(keys) > 250
    assert set(SCAN_OVERRIDES) <= keys  # no override outlives its field


@pytest.mark.parametrize("path, tp", SCAN_FIELDS, ids=[".".join(path) for path, _ in SCAN_FIELDS])
def test_a_bad_value_of_any_scan_field_is_refused_at_load(tmp_path, path, tp):
    key = ".".join(path)
    config_file = tmp_path / "scan.yaml"
    config_file.write_text(yaml.safe_dump(nested(path, bad_value(path, tp, SCAN_OVERRIDES))))
    with pytest.raises(ScannerError) as refused:
        load_scan_config(config_file)
    message = str(refused.value)
    assert message.startswith(f"{config_file}: "), message
    assert key in message and "\n" not in message, message


CALIBRATE_FIELDS = leaf_fields(CalibrateConfig)
CALIBRATE_OVERRIDES = {
    **{
        key: value
        for key, value in SCAN_OVERRIDES.items()
        if key.split(".")[0] in {"cell", "planner", "hardware", "driver"}
    },
    "placement.facing_azimuth_rad": float("nan"),
    "placement.facing_elevation_rad": 2.0,
}


@pytest.mark.parametrize(
    "path, tp", CALIBRATE_FIELDS, ids=[".".join(path) for path, _ in CALIBRATE_FIELDS]
)
def test_a_bad_value_of_any_calibration_field_is_refused_at_load(tmp_path, path, tp):
    key = ".".join(path)
    config_file = tmp_path / "calibrate.yaml"
    bad = bad_value(path, tp, CALIBRATE_OVERRIDES)
    config_file.write_text(yaml.safe_dump(nested(path, bad)))
    with pytest.raises(ScannerError) as refused:
        load_calibrate_config(config_file)
    message = str(refused.value)
    assert message.startswith(f"{config_file}: "), message
    assert key in message and "\n" not in message, message

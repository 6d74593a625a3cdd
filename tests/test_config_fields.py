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

CALIBRATE_OVERRIDES = {
    **{
        key: value
        for key, value in SCAN_OVERRIDES.items()
        if key.split(".")[0] in {"cell", "planner", "hardware", "driver"}
    },
    "placement.facing_azimuth_rad": float("nan"),
    "placement.facing_elevation_rad": 2.0,
}

# (the file's name, its loader, the overrides): each record's every field.
RECORDS = {
    ScanConfig: ("scan.yaml", load_scan_config, SCAN_OVERRIDES),
    CalibrateConfig: ("calibrate.yaml", load_calibrate_config, CALIBRATE_OVERRIDES),
}
CASES = [(cls, path, tp) for cls in RECORDS for path, tp in leaf_fields(cls)]


def test_the_table_walks_every_section():
    keys = {".".join(path) for cls, path, _ in CASES if cls is ScanConfig}
    assert {"object", "processing.primary_surface", "monitor.tracking.fps"} <= keys
    assert len(keys) > 250
    assert set(SCAN_OVERRIDES) <= keys  # no override outlives its field


@pytest.mark.parametrize(
    "cls, path, tp", CASES, ids=[f"{RECORDS[c][0]}:{'.'.join(p)}" for c, p, _ in CASES]
)
def test_a_bad_value_of_any_field_is_refused_at_load(tmp_path, cls, path, tp):
    name, load, overrides = RECORDS[cls]
    key = ".".join(path)
    config_file = tmp_path / name
    config_file.write_text(yaml.safe_dump(nested(path, bad_value(path, tp, overrides))))
    with pytest.raises(ScannerError) as refused:
        load(config_file)
    message = str(refused.value)
    assert message.startswith(f"{config_file}: "), message
    assert key in message and "\n" not in message, message

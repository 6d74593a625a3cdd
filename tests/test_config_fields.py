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

# Fields only some kinds of their record read, with the sibling that makes the record one of
# them: a nested record's keys the file leaves out keep the enclosing default (calibrate's board
# is a chessboard, which has no markers).
SIBLINGS = {
    "board.marker_m": {"kind": "charuco"},
    "board.dictionary": {"kind": "charuco"},
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
    parent = {path[-1]: bad_value(path, tp, overrides), **SIBLINGS.get(key, {})}
    config_file.write_text(yaml.safe_dump(nested(path[:-1], parent)))
    with pytest.raises(ScannerError) as refused:
        load(config_file)
    message = str(refused.value)
    assert message.startswith(f"{config_file}: "), message
    assert key in message and "\n" not in message, message


def test_a_nested_section_keeps_its_enclosing_defaults_for_the_keys_it_leaves_out(tmp_path):
    """A recording's matcher has a 5 px block and each view two partners, where the records'
    classes have 3 px and one: a file that sets one other key of those sections keeps them."""
    from scanner.configs.typed_yaml import load_yaml_file
    from scanner.recordings.settings import RecordingProcessing

    defaults = RecordingProcessing()
    assert defaults.stereo.block_size_px == 5 and defaults.pairing.pairs_per_view == 2
    path = tmp_path / "recording.yaml"
    path.write_text("stereo:\n  uniqueness_ratio_percent: 12\npairing:\n  min_angle_rad: 0.08\n")
    loaded = load_yaml_file(RecordingProcessing, path)
    assert loaded.stereo.uniqueness_ratio_percent == 12 and loaded.stereo.block_size_px == 5
    assert loaded.pairing.min_angle_rad == 0.08 and loaded.pairing.pairs_per_view == 2
    assert loaded.two_view.downscale == defaults.two_view.downscale
    # The calibration's board is a 10 x 7 chessboard; a file giving its squares' size keeps it.
    board = tmp_path / "calibrate.yaml"
    board.write_text("board:\n  spacing_m: 0.03\n")
    spec = load_calibrate_config(board).board
    assert (spec.kind, spec.cols, spec.rows, spec.spacing_m) == ("chessboard", 10, 7, 0.03)

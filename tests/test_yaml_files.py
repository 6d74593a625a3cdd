"""YAML reading and writing through libyaml: the same data and text as PyYAML's pure-Python
safe_load / safe_dump, and user errors for bad files."""

from __future__ import annotations

import math

import pytest
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml, yaml_text

RECORD = {
    "schema": 3,
    "object": "bunny: the 'Stanford' one",
    "X_WF": [[1.0, 0.0, 0.0, 0.123456789012345], [0.0, -1.0, 1e-17, -2.5e-05]],
    "q_rad": [0.1, -1.5707963267948966, math.pi],
    "flags": {"resumed": False, "note": None, "empty": [], "nested": {"b": 1, "a": 2}},
    "unicode": "Stäubli RX60 – 0.5 m",
    "multiline": "line one\nline two\n",
    "numbers_as_text": ["1.0", "yes", "null", "0o17"],
}


def test_written_text_is_what_safe_dump_writes_and_reads_back_the_same(tmp_path):
    text = yaml_text(RECORD)
    assert text == yaml.safe_dump(RECORD, sort_keys=False)
    path = tmp_path / "record.yaml"
    path.write_text(text)
    assert read_yaml(path, "record") == RECORD
    assert read_yaml(path, "record") == yaml.safe_load(text)


def test_bad_files_are_user_errors_naming_the_file(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("a: [1, 2\nb: 3\n")
    with pytest.raises(ScannerError, match=r"broken\.yaml: manifest is not valid YAML .*line"):
        read_yaml(broken, "manifest")
    with pytest.raises(ScannerError, match=r"missing\.yaml: cannot read manifest"):
        read_yaml(tmp_path / "missing.yaml", "manifest")
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ScannerError, match="not a text file"):
        read_yaml(binary, "manifest")

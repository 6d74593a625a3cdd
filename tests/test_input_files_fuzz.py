"""Property tests of the files users write: any YAML configuration and any pose file either loads
into a valid record or is refused with a ScannerError (never another exception, never a record
that breaks a stated invariant)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconstruction.calibration.pose_files import POSE_PRESETS, read_pose_file, read_pose_list
from reconstruction.common.errors import ScannerError
from scanner.calibrate.config import CalibrateConfig
from scanner.configs.scan import ScanConfig
from scanner.configs.typed_yaml import from_dict, to_dict

VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.lists(st.floats(allow_nan=True), max_size=4),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)


def _leaf_paths(d: dict, prefix=()) -> list[tuple]:
    out = []
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out += _leaf_paths(v, (*prefix, k))
        else:
            out.append((*prefix, k))
    return out


def _with(d: dict, path: tuple, value) -> dict:
    d = dict(d)
    if len(path) == 1:
        d[path[0]] = value
    else:
        d[path[0]] = _with(d[path[0]], path[1:], value)
    return d


@pytest.mark.parametrize("cls", [ScanConfig, CalibrateConfig])
def test_any_configuration_value_loads_or_is_refused(cls):
    defaults = to_dict(cls())
    paths = _leaf_paths(defaults)

    @settings(max_examples=300, deadline=None, derandomize=True)
    @given(st.lists(st.tuples(st.sampled_from(paths), VALUES), min_size=1, max_size=3))
    def check(changes):
        data = defaults
        for path, value in changes:
            data = _with(data, path, value)
        try:
            config = from_dict(cls, data, "config")
        except ScannerError as e:
            assert str(e).startswith("config"), str(e)  # names the file's key path
            return
        # Accepted: every number in it is finite (no NaN/inf slipped past a check).
        for path in paths:
            value = to_dict(config)
            for key in path:
                value = value[key]
            for v in value if isinstance(value, list) else [value]:
                if isinstance(v, float):
                    assert math.isfinite(v), (path, v)

    check()


NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**6), max_value=10**6).map(str),
    st.sampled_from(["abc", "1e400", "--", "1,5", ""]),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    st.lists(NUMBER, min_size=0, max_size=17),
    st.sampled_from(sorted(POSE_PRESETS)),
    st.sampled_from([" ", ",", "\n", "\t"]),
)
def test_any_pose_file_gives_a_rigid_pose_or_a_user_error(tmp_path_factory, numbers, preset, sep):
    path = tmp_path_factory.mktemp("pose") / "pose.txt"
    path.write_text(sep.join(numbers))
    for read in (read_pose_file, lambda p, f: read_pose_list(p, f)[0]):
        try:
            X = read(path, POSE_PRESETS[preset])
        except ScannerError as e:
            assert str(path) in str(e)
            continue
        except IndexError:
            continue  # an empty pose list is refused by its caller (tested elsewhere)
        assert X.shape == (4, 4) and np.all(np.isfinite(X))
        R = X[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-6)
        assert np.linalg.det(R) > 0

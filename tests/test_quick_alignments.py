"""The quick model's pass alignments kept in the scan manifest: only verified ones, read back as
written, dropped with the pass they belong to (and those after it) when it is scanned again,
and a damaged record refused naming the field."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose, rotation_about
from reconstruction.hangings.alignment import PassAlignment
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.quick_alignments import (
    quick_alignments,
    record_quick_alignments,
    without_passes_from,
)


def _alignment(hanging: int, failures=()) -> PassAlignment:
    T = make_pose(rotation_about(np.array([0.3, 0.4, 0.866]), 0.1 * hanging), [0.01, 0.0, hanging])
    return PassAlignment(hanging, T, 0.6, 4e-4, 0.01, 0.3, 0.25 * hanging, 9, tuple(failures))


def _store(tmp_path) -> CaptureStore:
    return CaptureStore.create(tmp_path / "scan", {"status": "running"})


def test_verified_alignments_are_kept_and_read_back(tmp_path):
    store = _store(tmp_path)
    record_quick_alignments(store, [_alignment(1), _alignment(2, ["overlap 0.05"])])
    record_quick_alignments(store, [_alignment(3)])
    kept = quick_alignments(SimpleNamespace(store=store))
    assert sorted(kept) == [1, 3]  # pass 2 did not verify
    for h in (1, 3):
        np.testing.assert_array_equal(kept[h].T, _alignment(h).T)
        assert kept[h].ambiguity == _alignment(h).ambiguity and kept[h].hypotheses == 9
        assert kept[h].verified and math.isnan(kept[h].overlap)  # measured again when used


def test_a_pass_scanned_again_takes_its_own_and_the_later_ones_with_it(tmp_path):
    store = _store(tmp_path)
    record_quick_alignments(store, [_alignment(1), _alignment(2), _alignment(3)])
    manifest = store.read_manifest()
    assert sorted(without_passes_from(manifest, 2)) == ["1"]
    assert without_passes_from(manifest, 1) is None


@pytest.mark.parametrize(
    "record, needle",
    [
        ({"T": [[1, 0], [0, 1]], "ambiguity": 0.1, "hypotheses": 3}, "T: expected a finite 4x4"),
        ({"T": np.eye(4).tolist(), "hypotheses": 3}, "expected T (4x4), ambiguity"),
        ({"T": (2 * np.eye(4)).tolist(), "ambiguity": 0.1, "hypotheses": 3}, "not a rotation"),
    ],
)
def test_a_damaged_record_is_refused_naming_the_field(tmp_path, record, needle):
    store = _store(tmp_path)
    manifest = store.read_manifest()
    store.write_manifest({**manifest, "quick_alignments": {"1": record}})
    with pytest.raises(ScannerError) as e:
        quick_alignments(SimpleNamespace(store=store))
    assert "scan.yaml: quick_alignments: 1" in str(e.value) and needle in str(e.value)
    assert yaml.safe_load(store.manifest_path.read_text())["quick_alignments"]  # left as it was

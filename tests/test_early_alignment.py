"""When a further pass's alignment is searched for during its capture: the quick models of the
passes before it from the end of the pass before (or its first view after a resume), the search
from a third of its views on (at least 3), once, not for the first pass, not again after an interruption that kept it, with auto and
fixed hangings alike; and what is kept of it afterwards (only a verified one; a search that
could not run leaves the search after the pass to decide)."""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.hangings.alignment import PassAlignment
from scanner.configs.scan import ScanConfig
from scanner.scan.hangings import HangingRunner
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.quick_alignments import quick_alignments, record_quick_alignments

HANGINGS = [[0, 1, 2, 3, 4, 5], [6, 7, 8, 9, 10, 11]]


class FakeAssessor:
    """Answers the early search with a prepared outcome, and records what it was asked."""

    def __init__(self, outcome) -> None:
        self.outcome, self.asked = outcome, []

    def passes_before(self, hangings, hanging, captured):
        self.asked.append(("before", hanging, sorted(captured)))

    def early_alignment(self, hangings, hanging, captured):
        self.asked.append((hanging, sorted(captured)))
        if isinstance(self.outcome, Exception):
            raise self.outcome
        return self.outcome


def _runner(tmp_path, outcome, hangings="auto") -> tuple[HangingRunner, FakeAssessor]:
    store = CaptureStore.create(tmp_path / "scan", {"status": "running"})
    config = replace(ScanConfig(), hangings=hangings)
    stream = SimpleNamespace(hanging=1)
    runner = HangingRunner(
        config, None, store, [], None, None, lambda stage: nullcontext(), None, stream
    )
    runner.hangings = [list(h) for h in HANGINGS]
    runner.assessor = FakeAssessor(outcome)
    return runner, runner.assessor


def _alignment(failures=()) -> PassAlignment:
    T = np.eye(4)
    T[:3, 3] = [0.01, 0.02, 0.0]
    return PassAlignment(1, T, 0.5, 4e-4, 0.01, 0.4, 0.2, 17, tuple(failures))


@pytest.mark.parametrize("hangings", ["auto", 2])
def test_it_starts_once_at_a_third_of_the_pass_and_a_verified_one_is_kept(tmp_path, hangings):
    runner, assessor = _runner(tmp_path, _alignment(), hangings)
    first = set(HANGINGS[0])
    runner._align_early(0, first)  # the first pass has nothing to align onto
    runner._prepare_early(2, first)  # there is no third pass
    assert not runner.early_before and not assessor.asked
    runner._prepare_early(1, first)  # the first pass ended: the models before the second
    runner._align_early(1, first | {6})  # made ready once
    runner._align_early(1, first | {6, 7})  # 2 of 6: too few for the search
    assert not runner.early and assessor.asked == [("before", 1, sorted(first))]
    runner._align_early(1, first | {6, 7, 8})
    runner._align_early(1, first | {6, 7, 8, 9})  # already under way
    runner._early_alignment_done(1)
    assert assessor.asked[1:] == [(1, sorted(first | {6, 7, 8}))]
    kept = quick_alignments(SimpleNamespace(store=runner.store))
    np.testing.assert_array_equal(kept[1].T, _alignment().T)
    assert kept[1].ambiguity == 0.2 and kept[1].hypotheses == 17


def test_not_for_a_whole_pass_nor_again_after_an_interruption(tmp_path):
    runner, assessor = _runner(tmp_path / "auto", _alignment())
    runner._align_early(1, set(range(12)))  # all captured: the search after the pass does it
    assert not runner.early
    record_quick_alignments(runner.store, [_alignment()])  # kept before an interruption
    runner._align_early(1, set(range(9)))
    assert not runner.early and not assessor.asked


@pytest.mark.parametrize(
    "outcome", [_alignment(["overlap 0.05 (need >= 0.2)"]), ScannerError("fewer than 2 views")]
)
def test_an_unverified_or_impossible_early_search_keeps_nothing(tmp_path, outcome):
    runner, assessor = _runner(tmp_path, outcome)
    runner._align_early(1, set(range(9)))
    runner._early_alignment_done(1)
    assert assessor.asked and quick_alignments(SimpleNamespace(store=runner.store)) == {}


def test_a_scan_that_stops_drops_the_search_not_yet_started(tmp_path):
    import threading

    runner, assessor = _runner(tmp_path, _alignment(), hangings=2)
    started, release = threading.Event(), threading.Event()

    def slow_before(hangings, hanging, captured):
        started.set()
        release.wait(10)
        assessor.asked.append(("before", hanging, sorted(captured)))

    assessor.passes_before = slow_before
    runner._align_early(1, set(range(9)))  # the models before, then the search, queued
    assert started.wait(10) and not runner.early[1].done()
    runner._stop_early()  # the scan ends (stopped) while the models before are made
    release.set()
    assert runner.early[1].cancelled()
    runner.early_before[1].result(timeout=10)  # the one under way ends on its own
    assert assessor.asked == [("before", 1, list(range(9)))]

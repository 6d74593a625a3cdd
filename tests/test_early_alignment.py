"""When a further pass's alignment is searched for during its capture (auto and fixed hangings
alike): the quick models of the passes before it from the end of the pass before (or its first
view after a resume), the search from a third of its views on (at least 3), once, not for the
first pass, not again after an interruption that kept it; what is kept of it afterwards (only
a verified one; a search that could not run leaves the search after the pass to decide); and
what a scan that stops drops."""

from __future__ import annotations

from contextlib import nullcontext
from types import SimpleNamespace

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.hangings.alignment import PassAlignment
from scanner.scan.early_alignment import EarlyAlignments
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


def _early(tmp_path, outcome) -> tuple[EarlyAlignments, FakeAssessor]:
    store = CaptureStore.create(tmp_path / "scan", {"status": "running"})
    assessor = FakeAssessor(outcome)
    return EarlyAlignments(store, True, lambda: assessor, lambda stage: nullcontext()), assessor


def _alignment(failures=()) -> PassAlignment:
    T = np.eye(4)
    T[:3, 3] = [0.01, 0.02, 0.0]
    return PassAlignment(1, T, 0.5, 4e-4, 0.01, 0.4, 0.2, 17, tuple(failures))


def test_it_starts_once_at_a_third_of_the_pass_and_a_verified_one_is_kept(tmp_path):
    early, assessor = _early(tmp_path, _alignment())
    first = set(HANGINGS[0])
    early.on_capture(HANGINGS, 0, first)  # the first pass has nothing to align onto
    early.prepare(HANGINGS, 2, first)  # there is no third pass
    assert not early.before and not assessor.asked
    early.prepare(HANGINGS, 1, first)  # the first pass ended: the models before the second
    early.on_capture(HANGINGS, 1, first | {6})  # made ready once
    early.on_capture(HANGINGS, 1, first | {6, 7})  # 2 of 6: too few for the search
    assert not early.searches and assessor.asked == [("before", 1, sorted(first))]
    early.on_capture(HANGINGS, 1, first | {6, 7, 8})
    early.on_capture(HANGINGS, 1, first | {6, 7, 8, 9})  # already under way
    early.done(1)
    assert assessor.asked == [("before", 1, sorted(first)), (1, sorted(first | {6, 7, 8}))]
    kept = quick_alignments(SimpleNamespace(store=early.store))
    np.testing.assert_array_equal(kept[1].T, _alignment().T)
    assert kept[1].ambiguity == 0.2 and kept[1].hypotheses == 17


def test_not_for_a_whole_pass_nor_again_after_an_interruption(tmp_path):
    early, assessor = _early(tmp_path, _alignment())
    early.on_capture(HANGINGS, 1, set(range(12)))  # all captured: the search after the pass
    assert not early.before and not early.searches
    record_quick_alignments(early.store, [_alignment()])  # kept before an interruption
    early.on_capture(HANGINGS, 1, set(range(9)))
    assert not early.searches and not assessor.asked


@pytest.mark.parametrize(
    "outcome", [_alignment(["overlap 0.05 (need >= 0.2)"]), ScannerError("fewer than 2 views")]
)
def test_an_unverified_or_impossible_early_search_keeps_nothing(tmp_path, outcome):
    early, assessor = _early(tmp_path, outcome)
    early.on_capture(HANGINGS, 1, set(range(9)))
    early.done(1)
    assert assessor.asked and quick_alignments(SimpleNamespace(store=early.store)) == {}


def test_a_scan_that_stops_drops_the_search_not_yet_started(tmp_path):
    import threading

    early, assessor = _early(tmp_path, _alignment())
    started, release = threading.Event(), threading.Event()

    def slow_before(hangings, hanging, captured):
        started.set()
        release.wait(10)
        assessor.asked.append(("before", hanging, sorted(captured)))

    assessor.passes_before = slow_before
    early.on_capture(HANGINGS, 1, set(range(9)))  # the models before, then the search, queued
    assert started.wait(10) and not early.searches[1].done()
    early.stop()  # the scan ends (stopped) while the models before are made
    release.set()
    assert early.searches[1].cancelled()
    early.before[1].result(timeout=10)  # the one under way ends on its own
    assert assessor.asked == [("before", 1, list(range(9)))]


def test_a_fixed_hangings_scan_runs_it(tmp_path):
    """The scan's runner asks for it whatever the presentation's pass count says."""
    from dataclasses import replace

    from scanner.configs.scan import ScanConfig
    from scanner.scan.hangings import HangingRunner

    store = CaptureStore.create(tmp_path / "scan", {"status": "running"})
    config = replace(ScanConfig(), hangings=2)
    stream = SimpleNamespace(hanging=1)
    runner = HangingRunner(
        config, None, store, [], None, None, lambda stage: nullcontext(), None, stream
    )
    runner.assessor = FakeAssessor(_alignment())
    runner.hangings = [list(h) for h in HANGINGS]
    runner.early.on_capture(runner.hangings, 1, set(range(9)))
    runner.early.done(1)
    assert runner.assessor.asked == [("before", 1, list(range(9))), (1, list(range(9)))]

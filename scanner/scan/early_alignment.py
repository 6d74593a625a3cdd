"""A further pass's alignment found while the pass is captured, with auto and fixed hangings
alike, so that its search does not run after the last picture.

The end of a pass starts the quick models of the passes before the next one (`prepare`), while
the object is presented anew (with `hangings: auto` they exist already; after a resume, the
pass's first view starts them); from a third of the next pass's views on (at least
EARLY_MIN_VIEWS), its alignment onto them is searched for on the views it has (`on_capture`).
After the pass (`done`), a verified result is kept in scan.yaml (`quick_alignments`) for the
auto decision and the reconstruction, which refine and verify it again. Both reuse the pairs the
scan's stream registered as the views arrived; the first pass's quick model corrects the mount
on them. One background thread: the jobs run in the order they were asked for, and the scan's
own thread uses the assessor only once every job started before is waited for.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from concurrent.futures import CancelledError, Future, ThreadPoolExecutor
from contextlib import AbstractContextManager

from reconstruction.common.errors import ScannerError
from scanner.scan.auto_hangings import HangingAssessor
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.quick_alignments import record_quick_alignments

log = logging.getLogger("scanner.scan.early_alignment")

# The fewest views of a pass its early alignment is searched on.
EARLY_MIN_VIEWS = 3


class EarlyAlignments:
    """The background work for the passes of one scan. `assessor()`: the scan's quick models
    (made on first use, shared with the auto decision); `timer(stage)`: the scan's stage
    timer (the waits are `early_alignment_wait`)."""

    def __init__(
        self,
        store: CaptureStore,
        streamed: bool,
        assessor: Callable[[], HangingAssessor],
        timer: Callable[[str], AbstractContextManager],
    ) -> None:
        self.store, self.streamed, self._assessor, self.timer = store, streamed, assessor, timer
        self.searches: dict[int, Future] = {}
        # The quick models of the passes before each pass (None once waited for).
        self.before: dict[int, Future | None] = {}
        self._pool: ThreadPoolExecutor | None = None

    def prepare(self, hangings: Sequence[Sequence[int]], hanging: int, captured: set[int]) -> None:
        """The quick models of the passes before `hanging` started, once (not for the first
        pass, a pass captured already, or one whose alignment was kept before an interruption;
        nothing without the scan's stream)."""
        if hanging == 0 or hanging >= len(hangings) or not self.streamed:
            return
        if hanging in self.before or set(hangings[hanging]) <= captured:
            return
        if str(hanging) in (self.store.read_manifest().get("quick_alignments") or {}):
            return  # found before an interruption
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="early-alignment")
        self.before[hanging] = self._pool.submit(
            self._assessor().passes_before, _lists(hangings), hanging, set(captured)
        )

    def on_capture(
        self, hangings: Sequence[Sequence[int]], hanging: int, captured: set[int]
    ) -> None:
        """After each capture of pass `hanging`: the models before it when not yet started,
        and the search once the pass has a third of its views (not all of them: the
        alignment after the pass searches then)."""
        self.prepare(hangings, hanging, captured)
        if hanging not in self.before or hanging in self.searches:
            return
        planned = hangings[hanging]
        got = [i for i in planned if i in captured]
        # From a third on, not half: on two cores beside the simulated cameras the search
        # started at half was still running 4-5 s after the last picture.
        if len(got) < max(EARLY_MIN_VIEWS, len(planned) // 3) or len(got) == len(planned):
            return
        # One job at a time: the search starts once the models before are made.
        self.searches[hanging] = self._pool.submit(
            self._assessor().early_alignment, _lists(hangings), hanging, set(captured)
        )
        log.info("pass %d: aligning it from its first %d views meanwhile", hanging + 1, len(got))

    def done(self, hanging: int) -> None:
        """Wait for every job started (a pass found captured after a resume is skipped, its
        job is not) and keep pass `hanging`'s alignment when it verified."""
        for h, before in self.before.items():
            if before is None:
                continue  # waited for already
            try:
                with self.timer("early_alignment_wait"):
                    before.result()
            except (ScannerError, CancelledError) as e:
                # The decision after the pass, or the reconstruction, makes them again.
                log.info("pass %d: no quick models of the passes before it (%s)", h + 1, e)
            self.before[h] = None
        future = self.searches.get(hanging)
        if future is None:
            return
        try:
            with self.timer("early_alignment_wait"):
                alignment = future.result()
        except ScannerError as e:
            # Too little of the pass to align yet: the alignment after the pass searches.
            log.info("pass %d: no early alignment (%s)", hanging + 1, e)
            return
        if alignment.verified:
            record_quick_alignments(self.store, [alignment])
        else:
            log.info(
                "pass %d: its first views did not align verifiably (%s); it is searched for "
                "again after the pass",
                hanging + 1,
                "; ".join(alignment.failures),
            )

    def stop(self) -> None:
        """The scan ends (stopped, or a pass never finished): what has not started is dropped;
        a search under way ends on its own (the process waits for it when it exits), its
        result unused: a resume searches again."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


def _lists(hangings: Sequence[Sequence[int]]) -> list[list[int]]:
    return [list(h) for h in hangings]

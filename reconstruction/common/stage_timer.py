"""Wall time per named stage, summed over repeated entries: what every report's timings use;
and the CPU time a run used, which bounds how fast it can be on a given number of cores."""

from __future__ import annotations

import resource
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")

# on_stage(stage, finished): told when a stage starts (False) and ends (True), e.g. by a
# progress display. Stages may run in parallel threads (the surfaces).
StageListener = Callable[[str, bool], None]


class StageTimer:
    """`with timer("icp"): ...` adds the block's wall time to `timer.seconds["icp"]`."""

    def __init__(
        self, seconds: dict[str, float] | None = None, on_stage: StageListener | None = None
    ) -> None:
        self.seconds: dict[str, float] = {} if seconds is None else seconds
        self.on_stage = on_stage

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        if self.on_stage is not None:
            self.on_stage(stage, False)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - t0
            if self.on_stage is not None:
                self.on_stage(stage, True)

    def call(self, stage: str, fn: Callable[..., T], *args) -> T:
        """fn(*args), timed as `stage`."""
        with self(stage):
            return fn(*args)


def cpu_seconds() -> float:
    """CPU time (user + system, s) used so far by this process and its finished children (the
    Poisson solver's process). Over a run, divided by the cores, it is the wall time the run
    cannot go below without removing computation, however well its stages overlap."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime

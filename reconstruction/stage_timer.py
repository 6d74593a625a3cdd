"""Wall time per named stage, summed over repeated entries: what every report's timings use."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")


class StageTimer:
    """`with timer("icp"): ...` adds the block's wall time to `timer.seconds["icp"]`."""

    def __init__(self, seconds: dict[str, float] | None = None) -> None:
        self.seconds: dict[str, float] = {} if seconds is None else seconds

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - t0

    def call(self, stage: str, fn: Callable[..., T], *args) -> T:
        """fn(*args), timed as `stage`."""
        with self(stage):
            return fn(*args)

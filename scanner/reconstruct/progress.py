"""Progress on stderr (tqdm), quiet when not on a terminal: the views of a scan, then the
stages of the reconstruction with an ETA."""

from __future__ import annotations

import sys
import threading

from tqdm import tqdm


class ProgressBar:
    def __init__(self, unit: str) -> None:
        self._unit = unit
        self._bar: tqdm | None = None

    def __enter__(self) -> ProgressBar:
        return self

    def update(self, done: int, total: int) -> None:
        if self._bar is None:
            self._bar = tqdm(
                total=total,
                initial=done,
                unit=self._unit,
                file=sys.stderr,
                disable=None,
                dynamic_ncols=True,
            )
        self._bar.n = done
        self._bar.refresh()

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.close()


# Typical share of each stage in a reconstruction (seconds of a 24-view scan on a 2-core
# machine): the bar advances by these, so its ETA is the remaining share at the pace so far.
# Stages not listed (a pose graph, an alignment of hangings) show their name and add nothing.
STAGE_WEIGHTS = {
    "stereo": 12.0,
    "filter": 5.0,
    "handeye_coarse": 2.0,
    "pairs": 1.5,
    "icp": 5.0,
    "handeye": 3.0,
    "fuse": 0.5,
    "poisson": 15.0,
    "tsdf": 0.0,  # beside Poisson
    "coverage": 1.0,
    "evaluate": 4.0,
    "write": 3.0,
}


class StageProgress:
    """A reconstruction's stages on one bar: `on_stage(stage, finished)` (a StageTimer
    listener) names the running stages and advances the bar when one first ends;
    `on_view()` advances the stereo stage by one capture of `captures`."""

    def __init__(self, captures: int, label: str = "reconstruct", file=None) -> None:
        self._label = label
        self._per_view = STAGE_WEIGHTS["stereo"] / max(captures, 1)
        self._done: set[str] = set()
        self._views_counted = 0.0
        self._running: list[str] = []
        self._lock = threading.Lock()
        self._bar = tqdm(
            total=sum(STAGE_WEIGHTS.values()),
            file=file or sys.stderr,
            disable=None,
            dynamic_ncols=True,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]",
            desc=label,
        )

    def on_stage(self, stage: str, finished: bool) -> None:
        with self._lock:
            if not finished:
                self._running.append(stage)
            else:
                if stage in self._running:
                    self._running.remove(stage)
                if stage not in self._done:
                    self._done.add(stage)
                    weight = STAGE_WEIGHTS.get(stage, 0.0)
                    if stage == "stereo":
                        weight = max(weight - self._views_counted, 0.0)
                    self._advance(weight)
            self._bar.set_description_str(f"{self._label}: {', '.join(self._running) or 'done'}")

    def on_view(self) -> None:
        with self._lock:
            if "stereo" not in self._done:
                self._views_counted += self._per_view
                self._advance(self._per_view)

    def _advance(self, weight: float) -> None:
        self._bar.update(min(weight, self._bar.total - self._bar.n))

    def close(self) -> None:
        self._bar.close()

"""The interface every presentation implements: what the scan loop asks of it between passes."""

from __future__ import annotations

import abc

import numpy as np

from reconstruction.evaluation.coverage import SeenSurface
from scanner.configs.scan import ScanConfig
from scanner.scan.world import ScanWorld
from scanner.scan_dir.captures import CaptureStore


class Presentation(abc.ABC):
    """How the object is presented in each pass of a scan (`scanner.scan.hangings` runs the
    passes; this says how the object gets from one pass to the next)."""

    kind: str
    # The most passes this presentation makes (None: the configuration's max_hangings).
    max_passes: int | None = None

    def __init__(self, config: ScanConfig, store: CaptureStore) -> None:
        self.config, self.store = config, store

    def begin(self, world: ScanWorld, current: int) -> ScanWorld:
        """Before the first pass this run scans (`current`: the pass the object is in now):
        record what the pass needs (a turntable's angle); the world as the presentation
        holds it."""
        return world

    @abc.abstractmethod
    def present(self, world: ScanWorld, index: int, request: dict | None, viewer=None) -> ScanWorld:
        """The world once the object is presented for pass `index` (0-based), as `request`
        (the scanner's plan for that pass, None with a fixed number of passes) asked."""

    @abc.abstractmethod
    def plan(self, index: int, seen: SeenSurface, view_directions: np.ndarray) -> dict | None:
        """The request for pass `index` from what the passes so far have seen (in the frame of
        the pass now): at least `words` (what is done, for the log and the report) and
        `expected_gain`; None when no further pass would show anything unseen."""

    def why(self, manifest: dict, fixed: str) -> dict[int, str]:
        """Why each further pass (0-based, from 1) was made: the scanner's reason where it asked
        for the pass (`hangings: auto`), else `fixed` after the number of passes."""
        asked = {e["hanging"]: e["next"] for e in manifest.get("hanging_log", []) if "next" in e}
        passes = len(manifest.get("hangings", []))
        fixed = f"a fixed number of passes (hangings: {self.config.hangings}), {fixed}"
        return {p: asked[p]["asked_because"] if p in asked else fixed for p in range(1, passes)}

    def report(self, manifest: dict) -> dict | None:
        """What the scan report says of the presentation (None: nothing beyond the hangings'
        own keys)."""
        return None

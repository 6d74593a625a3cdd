"""Hanging: the object hangs from the rod; between passes a person re-hangs it as the scanner
asks, in words and a picture (the next-best hanging), or at random with a fixed number of
hangings. The simulated operator follows with a person's error (robots/simulation/operator.py)."""

from __future__ import annotations

import numpy as np

from reconstruction.evaluation.coverage import SeenSurface
from scanner.reports.rehang_picture import write_rehang_picture
from scanner.scan.next_hanging import instruction, next_best_hanging
from scanner.scan.presentation.base import Presentation
from scanner.scan.world import ScanWorld


class Hanging(Presentation):
    kind = "hanging"

    def present(self, world: ScanWorld, index: int, request: dict | None, viewer=None) -> ScanWorld:
        return world.rehang(index, self.config.error_model.operator, request, viewer)

    def plan(self, index: int, seen: SeenSurface, view_directions: np.ndarray) -> dict | None:
        """The next-best turn, in words and a picture."""
        centre = np.array(self.config.scan_center_m)
        choice = next_best_hanging(seen, centre, self.config.views.radius_m, view_directions)
        if choice is None or choice.gain <= 0:
            return None
        # Beside the captures, not in results/: a reconstruction writes that folder anew.
        name = f"rehang_{index + 1}.png"
        picture = self.store.root / name
        write_rehang_picture(seen, choice.up_W, choice.clamp_W, centre, index, picture)
        return {
            "up_W": [float(x) for x in choice.up_W],
            "clamp_W": [float(x) for x in choice.clamp_W],
            "expected_gain": choice.gain,
            "words": instruction(choice, index, str(picture)),
            "picture": name,
        }

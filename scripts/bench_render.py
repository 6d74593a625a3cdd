"""Benchmark: seconds per simulated stereo pair (render + distortion + noise) at default size.

Prints one JSON line: {"seconds_per_stereo_pair", "width", "height", "pairs"}.
"""

from __future__ import annotations

import json
import time

from robots.models.workcell import WorkcellConfig
from robots.simulation.cell import create_simulation
from robots.simulation.truth import ErrorModel
from scanner.scan.preview import first_reachable_view

PAIRS = 20


def main() -> None:
    sim = create_simulation(WorkcellConfig(), "vase", ErrorModel(seed=0))
    sim.robot.teleport(first_reachable_view(sim, 0.5)[1])
    sim.camera.capture()  # the first render initialises VTK; not part of the steady state
    start = time.perf_counter()
    for _ in range(PAIRS):
        pair = sim.camera.capture()
    elapsed = time.perf_counter() - start
    height, width = pair.left.shape[:2]
    print(
        json.dumps(
            {
                "seconds_per_stereo_pair": round(elapsed / PAIRS, 4),
                "width": width,
                "height": height,
                "pairs": PAIRS,
            }
        )
    )


if __name__ == "__main__":
    main()

"""Where a table or turntable should stand: the share of the viewpoint sphere the arm reaches
around candidate object centres with the support in the cell.

For each centre of a grid in front of the arm (x, z; y = 0), the share of a coarse sphere of
the views' radius (directions in the elevation band above the support, each tried at several
camera rolls) from which the camera looks at the centre with an IK solution collision-free in
the planner's view of the cell with that presentation's carrier (planners/reach.py:
`sphere_share`). Prints one JSON line: per centre its share, and the best. The cell's
`support_top_m` is the measured choice (robots/models/workcell.py says why).
`--presentation`, `--xs`, `--zs`, `--elevations` (degrees) change the grid.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace

from planners.reach import ReachSettings, sphere_share
from robots.arms.default import arm_of
from scanner.configs.scan import ScanConfig
from scanner.scan.world import software_camera


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--presentation", choices=("table", "turntable"), default="table")
    parser.add_argument("--xs", type=_floats, default=_floats("0.6,0.65,0.7,0.75,0.8"))
    parser.add_argument("--zs", type=_floats, default=_floats("0.13,0.17,0.21,0.25"))
    parser.add_argument("--elevations", type=_floats, default=_floats("-10,85"))
    args = parser.parse_args()
    config = ScanConfig()
    model, X_FC = software_camera(config)
    low, high = (math.radians(e) for e in args.elevations)
    settings = ReachSettings(directions=96, rolls=4, elevation_min_rad=low, elevation_max_rad=high)
    shares = []
    for x in args.xs:
        for z in args.zs:
            cell = replace(config.cell, object_center_m=(x, 0.0, z))
            share = sphere_share(
                arm_of(config.robot),
                cell,
                X_FC,
                model.X_CR,
                config.views.radius_m,
                settings,
                presentation=args.presentation,
            )
            shares.append({"object_center_m": [x, 0.0, z], "share": round(share, 3)})
    best = max(shares, key=lambda s: s["share"])
    print(json.dumps({"presentation": args.presentation, "best": best, "centres": shares}))


if __name__ == "__main__":
    main()

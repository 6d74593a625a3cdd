"""The unit rule of every file the product writes, in one place.

- YAML records (configuration, scan.yaml, capture.yaml, calibration.yaml, reconstruction.yaml,
  truth.yaml) are SI: metres, radians, seconds; poses as 4x4 matrices in metres.
- Reports (report.json, report.txt, summary.md, printed lines) give accuracy figures (errors,
  residuals, scatter, distances between surfaces) in millimetres and degrees, and say so in the
  key (`_mm`, `_deg`); every other quantity in a report (poses, sizes, durations) stays SI with
  its unit in the key; image quantities are in pixels (`_px`).
"""

from __future__ import annotations

import math


def mm(length_m: float) -> float:
    return 1e3 * float(length_m)


def deg(angle_rad: float) -> float:
    return math.degrees(float(angle_rad))

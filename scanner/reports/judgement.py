"""What each reported figure means and when it is good: one definition and one band per figure,
used by every summary (scan, reconstruct, merge, inspect; calibration: scanner/calibrate/judge.py).

Bands come from the physics of the default rig and from the benchmarks: at 0.5 m SGBM's depth
quantisation is ~0.1 mm and the median depth error per view ~0.2 mm, so an observed-surface
Chamfer of 0.2-0.3 mm is what this rig does well (the benchmark objects measure 0.22-0.46 mm),
and a hung object shows about 70 % of its surface to one hanging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Figure:
    """One reported figure: `good` and `poor` are thresholds in the figure's unit; between
    them it is "fair". `higher_is_better` says which way they point."""

    label: str
    unit: str
    definition: str
    good: float
    poor: float
    higher_is_better: bool = False

    def verdict(self, value: float | None) -> str:
        if value is None or not math.isfinite(value):
            return "unknown"
        if self.higher_is_better:
            return "good" if value >= self.good else "poor" if value < self.poor else "fair"
        return "good" if value <= self.good else "poor" if value > self.poor else "fair"

    def band(self) -> str:
        sign = (">=", "<") if self.higher_is_better else ("<=", ">")
        unit = f" {self.unit}" if self.unit else ""
        return f"good {sign[0]} {self.good:g}{unit}, poor {sign[1]} {self.poor:g}{unit}"


FIGURES: dict[str, Figure] = {
    "chamfer_observed_mm": Figure(
        "Chamfer, observed surface",
        "mm",
        "mean of the two mean distances model -> truth and seen truth -> model",
        0.3,
        0.6,
    ),
    "accuracy_p90_mm": Figure(
        "accuracy p90", "mm", "90 % of the model's surface lies within this of the truth", 0.5, 1.0
    ),
    "fscore_observed_1mm": Figure(
        "F-score at 1 mm, observed",
        "",
        "harmonic mean of precision and recall at 1 mm, on the surface some view saw",
        0.9,
        0.7,
        True,
    ),
    "completeness_observed_2mm": Figure(
        "completeness at 2 mm, observed",
        "",
        "share of the seen true surface within 2 mm of the model",
        0.95,
        0.85,
        True,
    ),
    "observed_fraction": Figure(
        "observed fraction",
        "",
        "share of the true surface both cameras of some view had in view (unoccluded, "
        "within 80 deg of facing each); stereo measures nothing else, so the rest cannot be "
        "in the model",
        0.95,
        0.8,
        True,
    ),
    "observable_fraction": Figure(
        "observable fraction",
        "",
        "share of the true surface a camera at the scan's distance could see from some "
        "direction all round (facing within 80 deg, unoccluded): what any scan can show; the "
        "rest (inside a spout, a slot) the closed model can only bridge",
        0.99,
        0.95,
        True,
    ),
    "completeness_observable_2mm": Figure(
        "completeness at 2 mm, observable surface",
        "",
        "share of the observable true surface within 2 mm of the model: whole-object "
        "completeness without what no camera can see",
        0.97,
        0.9,
        True,
    ),
    "chamfer_mm": Figure(
        "Chamfer, whole object",
        "mm",
        "as above over the whole true surface: the unseen part (e.g. a hung object's top) "
        "counts as missing, so it is large unless the object was seen all round",
        0.5,
        2.0,
    ),
    "fscore_1mm": Figure(
        "F-score at 1 mm, whole object", "", "as above over the whole true surface", 0.9, 0.7, True
    ),
    "fscore_2mm": Figure("F-score at 2 mm, whole object", "", "as above at 2 mm", 0.95, 0.8, True),
    "completeness_2mm": Figure(
        "completeness at 2 mm, whole object",
        "",
        "share of the whole true surface within 2 mm of the model",
        0.95,
        0.8,
        True,
    ),
    "handeye_error_mm": Figure(
        "hand-eye error, translation",
        "mm",
        "distance of the camera origin under the estimated X_FC from the true one",
        0.5,
        1.0,
    ),
    "handeye_error_deg": Figure(
        "hand-eye error, rotation", "deg", "angle between estimated and true X_FC", 0.1, 0.3
    ),
    "coverage_estimate": Figure(
        "coverage estimate (no truth)",
        "",
        "share of the model's closed surface both cameras of some view had in view, judged "
        "from the data alone",
        0.95,
        0.8,
        True,
    ),
    "rms_mm": Figure("deviation RMS", "mm", "root mean square of the signed deviations", 0.3, 0.6),
    "p90_abs_mm": Figure(
        "deviation p90", "mm", "90 % of the deviations are smaller than this", 0.5, 1.0
    ),
}

# The order summaries list the truth metrics in: what the sensor did first, then coverage.
TRUTH_FIGURES = (
    "chamfer_observed_mm",
    "accuracy_p90_mm",
    "fscore_observed_1mm",
    "completeness_observed_2mm",
    "observed_fraction",
    "chamfer_mm",
    "fscore_1mm",
    "fscore_2mm",
    "completeness_2mm",
    "observable_fraction",
    "completeness_observable_2mm",
)


def figure_row(key: str, value: float) -> str:
    """A markdown table row: figure, value with unit, verdict, band, definition."""
    f = FIGURES[key]
    unit = f" {f.unit}" if f.unit else ""
    return (
        f"| {f.label} | {value:.3f}{unit} | **{f.verdict(value)}** | {f.band()} | {f.definition} |"
    )


TABLE_HEAD = ("| figure | value | verdict | band | meaning |", "|---|---|---|---|---|")

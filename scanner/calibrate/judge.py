"""Good / fair / poor bands for the figures of a calibration report, each with its definition.

A user without the simulator's truth decides from these whether to use a calibration. The bands
are for the product's class of set-up (a wrist stereo rig of ~1 Mpx at 0.3-0.5 m from a printed
board, an arm of the RX60's class); each band's reason is in its definition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Band:
    """A figure (in `unit`) is good below `good`, poor above `poor`, fair in between."""

    name: str
    unit: str
    good: float
    poor: float
    definition: str

    def verdict(self, value: float) -> str:
        if value is None or not math.isfinite(value):
            return "unknown"
        return "good" if value < self.good else "poor" if value > self.poor else "fair"


BANDS = {
    "reprojection_rms_px": Band(
        "hand-eye reprojection RMS",
        "px",
        0.3,
        1.0,
        "detected board corners vs. corners projected through X_WF X_FC and the board pose, "
        "robot poses as reported",
    ),
    "stereo_rms_px": Band(
        "stereo calibration RMS",
        "px",
        0.3,
        1.0,
        "OpenCV stereoCalibrate's corner reprojection error over both cameras",
    ),
    "camera_rms_px": Band(
        "camera calibration RMS",
        "px",
        0.3,
        1.0,
        "OpenCV calibrateCamera's corner reprojection error",
    ),
    "epipolar_median_px": Band(
        "rectified epipolar error (median)",
        "px",
        0.2,
        0.5,
        "row difference of the same board corner in the rectified pair; stereo matching "
        "searches along rows, so it should stay well under 1 px",
    ),
    "board_scatter_max_mm": Band(
        "board-in-base scatter (max)",
        "mm",
        0.5,
        2.0,
        "largest distance of one pose's board origin X_WF X_FC X_CB from their mean: robot "
        "and hand-eye errors together",
    ),
    "X_FC_sigma_mm": Band(
        "X_FC translation sigma (largest axis)",
        "mm",
        0.1,
        0.5,
        "1-sigma uncertainty of the hand-eye translation from the refinement's covariance "
        "(a scan's registration corrects ~1 mm)",
    ),
    "X_FC_sigma_deg": Band(
        "X_FC rotation sigma (largest axis)",
        "deg",
        0.03,
        0.1,
        "1-sigma uncertainty of the hand-eye rotation, including the last joint's zero offset "
        "that no hand-eye data can separate from X_FC",
    ),
}


def figure_lines(values: dict) -> list[str]:
    """One line per figure present in `values` (keys of BANDS): value, unit, verdict, meaning
    and band."""
    lines = []
    for key, band in BANDS.items():
        value = values.get(key)
        if value is None:
            continue
        lines.append(
            f"  {band.name}: {value:.3f} {band.unit} [{band.verdict(value)}] - {band.definition}"
            f"; good < {band.good:g} {band.unit}, poor > {band.poor:g} {band.unit}"
        )
    return lines


def overall(values: dict) -> str:
    """The worst verdict of the figures present."""
    order = ("good", "fair", "poor")
    verdicts = [b.verdict(values[k]) for k, b in BANDS.items() if values.get(k) is not None]
    known = [v for v in verdicts if v in order]
    return max(known, key=order.index) if known else "unknown"

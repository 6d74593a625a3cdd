"""Good / fair / poor bands for the figures of a calibration report, each with its definition.

A user without the simulator's truth decides from these whether to use a calibration. The bands
are for the product's class of set-up (a wrist stereo rig of ~1 Mpx at 0.3-0.5 m from a printed
board, an arm of the RX60's class); each band's reason is in its definition.
"""

from __future__ import annotations

from scanner.reports.judgement import Figure

BANDS = {
    "reprojection_rms_px": Figure(
        "hand-eye reprojection RMS",
        "px",
        "detected board corners vs. corners projected through X_WF X_FC and the board pose, "
        "robot poses as reported",
        0.3,
        1.0,
    ),
    "stereo_rms_px": Figure(
        "stereo calibration RMS",
        "px",
        "OpenCV stereoCalibrate's corner reprojection error over both cameras",
        0.3,
        1.0,
    ),
    "camera_rms_px": Figure(
        "camera calibration RMS",
        "px",
        "OpenCV calibrateCamera's corner reprojection error",
        0.3,
        1.0,
    ),
    "epipolar_median_px": Figure(
        "rectified epipolar error (median)",
        "px",
        "row difference of the same board corner in the rectified pair; stereo matching "
        "searches along rows, so it should stay well under 1 px",
        0.2,
        0.5,
    ),
    "board_scatter_max_mm": Figure(
        "board-in-base scatter (max)",
        "mm",
        "largest distance of one pose's board origin X_WF X_FC X_CB from their mean: robot "
        "and hand-eye errors together",
        0.5,
        2.0,
    ),
    "held_out_mm": Figure(
        "held-out prediction",
        "mm",
        "board corners of each view predicted from its reported robot pose by a fit on the "
        "other views (k-fold), on the board: what a scan's uncorrected poses will see, the "
        "robot's own errors included (a scan's registration corrects ~1 mm)",
        0.3,
        1.0,
    ),
    "X_FC_sigma_mm": Figure(
        "X_FC translation sigma (largest axis)",
        "mm",
        "1-sigma uncertainty of the hand-eye translation: the larger of the refinement's "
        "covariance and the bootstrap over views, with the robot's stated accuracy that no "
        "hand-eye data can separate from X_FC (solver.robot_translation_sigma_m)",
        0.3,
        1.0,
    ),
    "X_FC_sigma_deg": Figure(
        "X_FC rotation sigma (largest axis)",
        "deg",
        "1-sigma uncertainty of the hand-eye rotation, as the translation's, with the robot's "
        "stated rotation accuracy (the last joint's zero among it)",
        0.05,
        0.2,
    ),
}


def figure_lines(values: dict) -> list[str]:
    """One line per figure present in `values` (keys of BANDS): value, unit, verdict, meaning
    and band."""
    lines = []
    for key, f in BANDS.items():
        value = values.get(key)
        if value is None:
            continue
        lines.append(
            f"  {f.label}: {value:.3f} {f.unit} [{f.verdict(value)}] - {f.definition}; {f.band()}"
        )
    return lines


def overall(values: dict) -> str:
    """The worst verdict of the figures present."""
    order = ("good", "fair", "poor")
    verdicts = [b.verdict(values[k]) for k, b in BANDS.items() if values.get(k) is not None]
    known = [v for v in verdicts if v in order]
    return max(known, key=order.index) if known else "unknown"

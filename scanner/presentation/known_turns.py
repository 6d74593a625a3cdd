"""A turntable scan's known turns, read back for its reconstruction: the angle of each pass
(the manifest's `turntable_angles_rad`) and the nominal axis (the cell model's turntable)."""

from __future__ import annotations

import math

import numpy as np

from reconstruction.hangings.merge import verified_turns
from reconstruction.hangings.turntable import Axis, KnownTurns
from robots.models.turntable import turntable_geometry
from scanner.scan_dir.manifest import SavedScan


def known_turns(scan: SavedScan, passes: int | None = None) -> KnownTurns | None:
    """None unless the scan stood on a turntable and recorded an angle for each of its first
    `passes` passes (None: all of them; the manifest read now, as a scan in progress writes
    it)."""
    angles = scan.store.read_manifest().get("turntable_angles_rad", [])
    passes = len(scan.hangings) if passes is None else passes
    if scan.config.presentation != "turntable" or len(angles) < passes:
        return None
    g = turntable_geometry(scan.config.cell)
    return KnownTurns(tuple(float(a) for a in angles), Axis(np.array(g.p_top_W), g.u_W))


def turntable_report(turns: KnownTurns, alignments) -> dict:
    """Whether each pass's known turn verified without the search, and the axis the verified
    turns calibrate (its offset and tilt from the cell model's)."""
    axis = turns.calibrated(verified_turns(alignments))
    p0, u0 = turns.nominal.p_W, turns.nominal.u_W
    # The offset is measured in the plane through the nominal point across the axis.
    along = (p0 - axis.p_W) @ axis.u_W
    offset = axis.p_W + along * axis.u_W - p0
    return {
        "angles_deg": [math.degrees(a) for a in turns.angles_rad],
        "known_turn_verified": [a.from_known_turn for a in alignments],
        "axis_calibrated": bool(verified_turns(alignments)),
        "axis_offset_mm": 1e3 * float(np.linalg.norm(offset)),
        "axis_tilt_deg": math.degrees(math.acos(float(np.clip(axis.u_W @ u0, -1.0, 1.0)))),
    }

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
    manifest = scan.store.read_manifest()
    angles = manifest.get("turntable_angles_rad", [])
    passes = len(scan.hangings) if passes is None else passes
    if scan.config.presentation != "turntable" or len(angles) < passes:
        return None
    g = turntable_geometry(scan.config.cell)
    # Passes laid on another face (scan/presentation/turntable.py) end the known turns.
    laid = [int(p) for p in manifest.get("turntable_laid_passes", {})]
    return KnownTurns(
        tuple(float(a) for a in angles),
        Axis(np.array(g.p_top_W), g.u_W),
        min(laid) if laid else None,
    )


def true_turntable_axis(scan: SavedScan, truth) -> Axis | None:
    """The simulated turntable's true axis (None without the simulator's truth)."""
    if truth is None:
        return None
    from robots.simulation.turntable import true_axis

    return true_axis(scan.config.cell, scan.config.error_model.seed)


def turntable_report(turns: KnownTurns, alignments, truth: Axis | None = None) -> dict:
    """Whether each pass's known turn verified without the search, and the axis the verified
    turns calibrate (its offset and tilt from the cell model's; with the simulator's `truth`,
    from the true axis too)."""
    axis = turns.calibrated(verified_turns(alignments))
    turned = [a for a in alignments if turns.known(a.hanging)]
    out = {
        "angles_deg": [math.degrees(a) for a in turns.angles_rad],
        "known_turn_verified": [a.from_known_turn for a in alignments],
        "axis_calibrated": bool(verified_turns(turned)),
    }
    offset_m, tilt_rad = _apart(axis, turns.nominal)
    out.update(axis_offset_mm=1e3 * offset_m, axis_tilt_deg=math.degrees(tilt_rad))
    if truth is not None:
        offset_m, tilt_rad = _apart(axis, truth)
        out.update(axis_error_mm=1e3 * offset_m, axis_error_deg=math.degrees(tilt_rad))
    return out


def _apart(axis: Axis, reference: Axis) -> tuple[float, float]:
    """How far `axis` passes from the reference's point (m, across it) and the angle between
    their directions (rad)."""
    d = reference.p_W - axis.p_W
    across = d - (d @ axis.u_W) * axis.u_W
    cos = float(np.clip(axis.u_W @ reference.u_W, -1.0, 1.0))
    return float(np.linalg.norm(across)), math.acos(cos)

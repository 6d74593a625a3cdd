"""Turntable: the object stands on a motorised turntable; between passes the scanner turns it.

With `hangings: auto` the scanner chooses each turn from what the passes so far have seen (the
next-best turn, `next_turn.py`); with a fixed number N of passes it turns by 360/N deg each
time. The angle the turntable reports after each turn is recorded in the scan's manifest
(`turntable_angles_rad`, one per pass: every capture of a pass was taken at its angle), so a
resumed scan and the reconstruction know it: the known turn is the starting guess of the pass
alignment (reconstruction/hangings/turntable.py), which still verifies it.

A turntable that does not answer, or reports another angle than it was told, is refused: before
anything moves (`turntable_check.check_turntable`, exit 2), or during the scan
(`TurntableStoppedError`, exit 5: the captures so far are kept and `--resume` turns it again).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction.evaluation.coverage import SeenSurface
from robots.drivers.interfaces import TurntableDriver
from robots.simulation.truth import hung_pose_of
from robots.simulation.turntable import SimulatedTurntable, true_axis
from scanner.scan.presentation.base import Presentation
from scanner.scan.presentation.next_turn import next_best_turn, wrapped
from scanner.scan.presentation.turntable_check import TurntableStoppedError, turn
from scanner.scan.world import ScanWorld

ANGLES_KEY = "turntable_angles_rad"


class Turntable(Presentation):
    kind = "turntable"
    driver: TurntableDriver | None = None

    def _angles(self) -> list[float]:
        return [float(a) for a in self.store.read_manifest().get(ANGLES_KEY, [])]

    def begin(self, world: ScanWorld, current: int) -> ScanWorld:
        angles = self._angles()
        if world.turntable is not None:
            self.driver = world.turntable
        else:
            # The simulated turntable, at the angle of the pass the scan is in (a resume).
            X_WO_zero = hung_pose_of(self.store.root / "truth.yaml", 0)
            if X_WO_zero is None:
                X_WO_zero = world.sim.truth.X_WO
            axis = true_axis(self.config.cell, self.config.error_model.seed)
            angle = angles[current] if current < len(angles) else 0.0
            self.driver = SimulatedTurntable(X_WO_zero, axis, angle)
        if not angles:
            self.store.update_manifest(**{ANGLES_KEY: [float(self.driver.angle_rad())]})
        return world

    def present(self, world: ScanWorld, index: int, request: dict | None, viewer=None) -> ScanWorld:
        angles = self._angles()
        if request is not None:
            target = float(request["angle_rad"])
        elif index < len(angles):  # a pass scanned again: at its angle (absolute, still valid)
            target = angles[index]
        else:  # a fixed number of passes: evenly around
            target = wrapped(angles[0] + 2 * math.pi * index / self.config.first_hangings)
        reported, problem = turn(self.driver, target)
        if problem:
            self.store.update_manifest(status="interrupted", pending_rehang=index)
            captured = len(self.store.captured_indices())
            raise TurntableStoppedError(
                f"turntable: {problem} before pass {index + 1}; the {captured} captures so far "
                f"are kept: continue with: scanner scan --resume {self.store.root}"
            )
        self.store.update_manifest(
            **{ANGLES_KEY: [*angles[:index], reported, *angles[index + 1 :]]}
        )
        if world.sim is not None and isinstance(self.driver, SimulatedTurntable):
            world = world.with_object_at(self.driver.X_WO(), viewer)
        return world

    def plan(self, index: int, seen: SeenSurface, view_directions: np.ndarray) -> dict | None:
        """The next-best turn from the angle of the pass now."""
        angles = self._angles()
        now = angles[index - 1]
        choice = next_best_turn(
            seen,
            np.array(self.config.scan_center_m),
            self.config.views.radius_m,
            view_directions,
            [wrapped(a - now) for a in angles[:index]],
        )
        if choice is None or choice.gain <= 0:
            return None
        target = wrapped(now + choice.turn_rad)
        return {
            "angle_rad": target,
            "turn_rad": choice.turn_rad,
            "expected_gain": choice.gain,
            "words": (
                f"pass {index + 1}: turning the turntable by {math.degrees(choice.turn_rad):+.0f} "
                f"deg to {math.degrees(target):.0f} deg, where the views are expected to see "
                f"{100 * choice.gain:.1f} % of the surface not seen so far"
            ),
        }

    def report(self, manifest: dict) -> dict:
        angles = [float(a) for a in manifest.get(ANGLES_KEY, [])]
        why = self.why(manifest, "turned evenly around")
        passes = []
        for p, angle in enumerate(angles):
            record = {"pass": p + 1, "angle_deg": math.degrees(angle)}
            if p > 0:
                record["turn_deg"] = math.degrees(wrapped(angle - angles[p - 1]))
                record["why"] = why.get(p, "-")
            passes.append(record)
        return {"kind": self.kind, "passes": passes}

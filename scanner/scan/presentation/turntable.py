"""Turntable: the object stands on a motorised turntable; between passes the scanner turns it.

With `hangings: auto` the scanner chooses each turn from what the passes so far have seen (the
next-best turn, `next_turn.py`); with a fixed number N of passes it turns by 360/N deg each
time (N >= 3: by 360/(N - 1) deg, and the last pass is laid anew, below). The angle the
turntable reports after each turn is recorded in the scan's manifest
(`turntable_angles_rad`, one per pass: every capture of a pass was taken at its angle), so a
resumed scan and the reconstruction know it: the known turn is the starting guess of the pass
alignment (reconstruction/hangings/turntable.py), which still verifies it.

The turntable turns about the vertical only: the side it stands on stays unseen, whatever the
turn. A scan whose underside is still unseen ends with the object laid on another face onto the
turntable's disc (the next-best face, `next_face.py`, as on the table: a person lays it, the
simulated one with a person's error): the last pass a turntable scan may make
(`MAX_PASSES`), or an earlier one where no turn would show anything more (the turns come
first: their known turn aligns a pass without the search). A laid pass is recorded
(`turntable_laid_passes`: by pass, the face it was laid on); its turn is not known, so it and
every pass after it align by the search for hypotheses, as a hanging, and calibrate nothing of
the axis.

A turntable that does not answer, or reports another angle than it was told, is refused: before
anything moves (`turntable_check.check_turntable`, exit 2), or during the scan
(`TurntableStoppedError`, exit 5: the captures so far are kept and `--resume` turns it again).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction.evaluation.coverage import SeenSurface
from reconstruction.hangings.turntable import turn_about_axis
from robots.drivers.interfaces import TurntableDriver
from robots.simulation.truth import hung_pose_of
from robots.simulation.turntable import SimulatedTurntable, true_axis
from scanner.reconstruct.scan_views import support_plane
from scanner.scan.presentation.base import Presentation
from scanner.scan.presentation.laying import face_request, lay, quarter_turn
from scanner.scan.presentation.next_face import next_best_face
from scanner.scan.presentation.next_turn import next_best_turn, wrapped
from scanner.scan.presentation.turntable_check import TurntableStoppedError, turn
from scanner.scan.world import ScanWorld

ANGLES_KEY = "turntable_angles_rad"
LAID_KEY = "turntable_laid_passes"
# Passes of a turntable scan at most: two turns show the sides and the top the arm sees from
# above; the third lays the object on another face to show its underside.
MAX_PASSES = 3
SUPPORT_WORDS = "turntable's disc"


class Turntable(Presentation):
    kind = "turntable"
    max_passes = MAX_PASSES
    driver: TurntableDriver | None = None

    def _angles(self) -> list[float]:
        return [float(a) for a in self.store.read_manifest().get(ANGLES_KEY, [])]

    def _laid(self) -> dict[str, str]:
        """The passes laid on another face (by pass number from 0, as text): the face."""
        return dict(self.store.read_manifest().get(LAID_KEY, {}))

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
            if any(int(p) <= current for p in self._laid()):
                # Laid anew since the first pass: the pose now, turned back to the zero angle.
                X_WO_now = hung_pose_of(self.store.root / "truth.yaml", current)
                X_WO_now = world.sim.truth.X_WO if X_WO_now is None else X_WO_now
                X_WO_zero = turn_about_axis(axis.p_W, axis.u_W, -angle) @ X_WO_now
            self.driver = SimulatedTurntable(X_WO_zero, axis, angle)
        if not angles:
            self.store.update_manifest(**{ANGLES_KEY: [float(self.driver.angle_rad())]})
        return world

    def present(self, world: ScanWorld, index: int, request: dict | None, viewer=None) -> ScanWorld:
        angles = self._angles()
        passes = self.config.first_hangings
        if request is None and index >= len(angles) and index == passes - 1 >= 2:
            # A fixed number of three or more passes ends laid anew: the turns never show
            # the side the object stands on.
            request = quarter_turn(index, SUPPORT_WORDS)
        if request is not None and "down_W" in request:
            return self._lay(world, index, request, angles, viewer)
        if request is not None:
            target = float(request["angle_rad"])
        elif index < len(angles):  # a pass scanned again: at its angle (absolute, still valid)
            target = angles[index]
        else:  # a fixed number of passes: evenly around (the turned ones, before a lay)
            turned = passes - 1 if passes >= 3 else passes
            target = wrapped(angles[0] + 2 * math.pi * index / turned)
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

    def _lay(
        self, world: ScanWorld, index: int, request: dict, angles: list[float], viewer
    ) -> ScanWorld:
        """The object laid on another face onto the disc, the turntable where it stands."""
        angle = float(self.driver.angle_rad())
        # Recorded before anything moves: a resume knows the pass was laid, not turned.
        self.store.update_manifest(
            **{
                LAID_KEY: {**self._laid(), str(index): request.get("face", request["words"])},
                ANGLES_KEY: [*angles[:index], angle, *angles[index + 1 :]],
            }
        )
        world = lay(self.config, world, index, request, viewer)
        if world.sim is not None and isinstance(self.driver, SimulatedTurntable):
            axis = self.driver.axis
            self.driver.X_WO_zero = (
                turn_about_axis(axis.p_W, axis.u_W, -angle) @ world.sim.truth.X_WO
            )
        return world

    def plan(self, index: int, seen: SeenSurface, view_directions: np.ndarray) -> dict | None:
        """The next-best turn from the angle of the pass now; or the next-best face to lay the
        object on, where that shows more or the pass is the last a turntable scan makes."""
        angles = self._angles()
        now = angles[index - 1]
        centre = np.array(self.config.scan_center_m)
        radius = self.config.views.radius_m
        choice = None
        if not self._laid():  # after a lay, no turn is known: faces only
            used = [wrapped(a - now) for a in angles[:index]]
            support = support_plane(self.config)
            choice = next_best_turn(seen, centre, radius, view_directions, used, support=support)
        face = next_best_face(seen, centre, radius, view_directions)
        last = index >= min(self.config.max_hangings, MAX_PASSES) - 1
        # Turned while a turn shows anything: a known turn aligns the pass without the search.
        turns_done = choice is None or choice.gain < self.config.min_hanging_gain
        if face is not None and face.gain > 0 and (last or turns_done):
            request = face_request(seen, face, centre, index, self.store.root, SUPPORT_WORDS)
            why = "the last pass" if last else "no turn shows more"
            request["words"] += f" (laid, not turned: {why})"
            return request
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
        laid = manifest.get(LAID_KEY, {})
        why = self.why(manifest, "turned evenly around")
        why_laid = self.why(manifest, "the last laid anew: no turn shows what it stands on")
        passes = []
        for p, angle in enumerate(angles):
            record = {"pass": p + 1, "angle_deg": math.degrees(angle)}
            if str(p) in laid:
                record["laid_on"] = laid[str(p)]
                record["why"] = why_laid.get(p, "-")
            elif p > 0:
                record["turn_deg"] = math.degrees(wrapped(angle - angles[p - 1]))
                record["why"] = why.get(p, "-")
            passes.append(record)
        return {"kind": self.kind, "passes": passes}

"""Table: the object lies on the cell's support table (robots/models/table.py); between passes a
person lays it on another face, as the scanner asks in words and a picture.

The first pass: the object as put down, resting on a stable face. With `hangings: auto` each
further face is the next-best one (`next_face.py`: which of the model's stable resting poses
shows most of what is still unseen); with a fixed number of passes the person rolls it a
quarter turn towards the robot each time. The face asked for is recorded in the manifest
before anything moves (`table_faces`, by pass), so a resumed scan asks for the
same one and the report says which face each pass lay on and why. Nothing tells the software
the yaw the person laid it at: the pass alignment searches its hypotheses as for a hanging.
The simulated person follows with a person's error (robots/simulation/laying.py).
"""

from __future__ import annotations

import numpy as np

from reconstruction.evaluation.coverage import SeenSurface
from scanner.scan.presentation.base import Presentation
from scanner.scan.presentation.laying import face_request, lay, quarter_turn
from scanner.scan.presentation.next_face import next_best_face
from scanner.scan.world import ScanWorld

FACES_KEY = "table_faces"


class Table(Presentation):
    kind = "table"

    def _faces(self) -> dict:
        return dict(self.store.read_manifest().get(FACES_KEY, {}))

    def begin(self, world: ScanWorld, current: int) -> ScanWorld:
        faces = self._faces()
        if "0" not in faces:
            first = {"words": "as put down, on the face underneath"}
            self.store.update_manifest(**{FACES_KEY: {**faces, "0": first}})
        return world

    def present(self, world: ScanWorld, index: int, request: dict | None, viewer=None) -> ScanWorld:
        faces = self._faces()
        asked = faces.get(str(index)) if request is None else request
        if asked is None or "down_W" not in asked:
            asked = quarter_turn(index)
        # Recorded before anything moves: a resume asks for the same face.
        self.store.update_manifest(**{FACES_KEY: {**faces, str(index): asked}})
        return lay(self.config, world, index, asked, viewer)

    def plan(self, index: int, seen: SeenSurface, view_directions: np.ndarray) -> dict | None:
        """The next-best face to lay the object on, in words and a picture."""
        centre = np.array(self.config.scan_center_m)
        choice = next_best_face(seen, centre, self.config.views.radius_m, view_directions)
        if choice is None or choice.gain <= 0:
            return None
        return face_request(seen, choice, centre, index, self.store.root)

    def report(self, manifest: dict) -> dict:
        faces = manifest.get(FACES_KEY, {})
        why = self.why(manifest, "rolled a quarter turn towards the robot")
        passes = []
        for p in range(len(manifest.get("hangings", []))):
            face = faces.get(str(p))
            if face is None:
                continue
            record = {"pass": p + 1, "laid_on": face.get("face", face["words"])}
            if "down_W" in face:
                record["down_W"] = face["down_W"]
            if p > 0:
                record["why"] = why.get(p, "-")
            passes.append(record)
        return {"kind": self.kind, "passes": passes}

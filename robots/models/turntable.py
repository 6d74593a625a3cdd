"""The motorised turntable of the cell: a disc on a post under the object, turning about the
vertical through the scan centre.

Its top is where the object stands: half the object's size below the object's centre, which a
turntable's scan places above the cell's `support_top_m` (scanner/scan/layout.py: low and in
front of the arm, which sees the object from above and around). The object put on it settles
on the face of its hull underneath (robots/simulation/laying.py), as on the table. The disc is
small (a fifth of the object's size in radius): it hides only the object's footprint. Its
geometry is registered as collision geometry of the world, so the planner avoids it and the
cell filter removes its points like the rod's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Fractions of the object size: a disc that carries the object without hiding more of it than
# it must, and a post stiff enough to look like one.
DISC_RADIUS_FRACTION = 0.2
DISC_THICKNESS_M = 0.01
POST_RADIUS_M = 0.012


@dataclass(frozen=True)
class TurntableGeometry:
    """The disc (centre of its top face p_top_W, radius, thickness) and the post under it down
    to the table top (z = 0); the axis is the vertical through p_top_W. Metres."""

    p_top_W: tuple[float, float, float]
    disc_radius_m: float
    disc_thickness_m: float
    post_radius_m: float

    @property
    def u_W(self) -> np.ndarray:
        return np.array([0.0, 0.0, 1.0])


def turntable_geometry(cell) -> TurntableGeometry:
    """The turntable of a cell (a WorkcellConfig: its object centre and size)."""
    cx, cy, cz = cell.object_center_m
    top = cz - cell.object_size_m / 2
    return TurntableGeometry(
        (cx, cy, top), DISC_RADIUS_FRACTION * cell.object_size_m, DISC_THICKNESS_M, POST_RADIUS_M
    )


def add_turntable(plant, cell) -> None:
    """The disc and its post, welded to the world (visual and collision geometry)."""
    from pydrake.geometry import Cylinder
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import CoulombFriction

    g = turntable_geometry(cell)
    x, y, top = g.p_top_W
    world = plant.world_body()
    grey = np.array([0.3, 0.3, 0.32, 1.0])
    disc_z = top - g.disc_thickness_m / 2
    post_length = top - g.disc_thickness_m
    parts = (
        ("turntable_disc", Cylinder(g.disc_radius_m, g.disc_thickness_m), disc_z),
        ("turntable_post", Cylinder(g.post_radius_m, post_length), post_length / 2),
    )
    for name, shape, z in parts:
        X = RigidTransform(np.array([x, y, z]))
        plant.RegisterVisualGeometry(world, X, shape, name, grey)
        plant.RegisterCollisionGeometry(world, X, shape, name, CoulombFriction(0.5, 0.5))

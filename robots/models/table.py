"""The support table of the cell: a small square top on a square leg, where the object lies.

Its top is where the turntable's disc is: half the object's size below the object's centre,
which a table's scan places above the cell's `support_top_m` (scanner/scan/layout.py: low and
in front of the arm, which sees the object from above and around). The top is small (half the
object's size a side): it hides little more than the face the object lies on, and an object
lies stably on it as long as its centre of mass is over the top, which the person laying it
(and the simulated one) sees to. Its geometry is collision geometry of the world, so the planner
avoids it and the cell filter removes its points like the rod's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reconstruction.hangings.resting_poses import RestingPose

# The top's side as a fraction of the object size, and a leg stiff enough to look like one.
TOP_SIDE_FRACTION = 0.5
TOP_THICKNESS_M = 0.01
LEG_SIDE_M = 0.024


@dataclass(frozen=True)
class TableGeometry:
    """The top (centre of its upper face p_top_W, side, thickness) and the leg under it down
    to the cell's floor (z = 0). Metres."""

    p_top_W: tuple[float, float, float]
    top_side_m: float
    top_thickness_m: float
    leg_side_m: float


def table_geometry(cell) -> TableGeometry:
    """The support table of a cell (a WorkcellConfig: its object centre and size)."""
    cx, cy, cz = cell.object_center_m
    top = cz - cell.object_size_m / 2
    return TableGeometry(
        (cx, cy, top), TOP_SIDE_FRACTION * cell.object_size_m, TOP_THICKNESS_M, LEG_SIDE_M
    )


def lying_pose(
    cell, R_WO: np.ndarray, vertices_O: np.ndarray, com_O: np.ndarray, offset_W=(0.0, 0.0)
) -> np.ndarray:
    """The object's pose X_WO lying on the table turned by `R_WO` (a resting pose's rotation,
    any yaw): its centre of mass over the top's centre moved by `offset_W` (x, y), its lowest
    point on the top."""
    g = table_geometry(cell)
    v = np.asarray(vertices_O, float) @ np.asarray(R_WO, float).T
    com = np.asarray(R_WO, float) @ np.asarray(com_O, float)
    X = np.eye(4)
    X[:3, :3] = R_WO
    X[:3, 3] = [
        g.p_top_W[0] + offset_W[0] - com[0],
        g.p_top_W[1] + offset_W[1] - com[1],
        g.p_top_W[2] - float(v[:, 2].min()),
    ]
    return X


def nearest_pose(poses: tuple[RestingPose, ...], down_O: np.ndarray) -> RestingPose:
    """The resting pose whose face points most nearly along `down_O` (object frame): where an
    object put down with that side underneath settles."""
    d = np.asarray(down_O, float) / np.linalg.norm(down_O)
    return max(poses, key=lambda p: float(p.down_O @ d))


def add_table(plant, cell) -> None:
    """The top and its leg, welded to the world (visual and collision geometry)."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import CoulombFriction

    g = table_geometry(cell)
    x, y, top = g.p_top_W
    world = plant.world_body()
    colour = np.array([0.45, 0.4, 0.35, 1.0])
    leg_length = top - g.top_thickness_m
    parts = (
        (
            "table_top",
            Box(g.top_side_m, g.top_side_m, g.top_thickness_m),
            top - g.top_thickness_m / 2,
        ),
        ("table_leg", Box(g.leg_side_m, g.leg_side_m, leg_length), leg_length / 2),
    )
    for name, shape, z in parts:
        X = RigidTransform(np.array([x, y, z]))
        plant.RegisterVisualGeometry(world, X, shape, name, colour)
        plant.RegisterCollisionGeometry(world, X, shape, name, CoulombFriction(0.5, 0.5))

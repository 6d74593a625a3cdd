"""Remove cloud points that lie on the robot, its tool, the rod or the cell (Drake geometry).

The Kinect papers in the seeds remove the robot's own points with cylinders/polygons around the
links; here the same primitives the planner collides with are used, posed by Drake at the
recorded joint configuration, with a margin. Distances are evaluated in numpy, vectorised over
points, per primitive (boxes, cylinders, spheres, capsules). The object's keep-out volume is
never used: its points are what we want.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydrake.geometry import Box, Capsule, Cylinder, Role, Sphere

from robots.models.workcell import OBJECT_BODY, Workcell


@dataclass(frozen=True, eq=False)
class _Primitive:
    kind: str
    size: tuple[float, ...]
    geometry_id: object = None  # posed by Drake at the configuration
    X_WG: np.ndarray | None = None  # or fixed in the world


def _signed_distance(kind: str, size: tuple[float, ...], p_GQ: np.ndarray) -> np.ndarray:
    """Signed distance (m, negative inside) of points p_GQ (N, 3) to a primitive in its frame G."""
    if kind == "sphere":
        return np.linalg.norm(p_GQ, axis=1) - size[0]
    if kind == "box":
        q = np.abs(p_GQ) - np.asarray(size) / 2
        outside = np.linalg.norm(np.maximum(q, 0), axis=1)
        return outside + np.minimum(q.max(axis=1), 0)
    if kind == "cylinder":
        radius, half = size[0], size[1] / 2
        d = np.stack([np.linalg.norm(p_GQ[:, :2], axis=1) - radius, np.abs(p_GQ[:, 2]) - half], 1)
        return np.linalg.norm(np.maximum(d, 0), axis=1) + np.minimum(d.max(axis=1), 0)
    if kind == "capsule":
        radius, half = size[0], size[1] / 2
        z = np.clip(p_GQ[:, 2], -half, half)
        return np.linalg.norm(p_GQ - np.stack([0 * z, 0 * z, z], 1), axis=1) - radius
    raise ValueError(kind)


def _bounding_radius(kind: str, size: tuple[float, ...]) -> float:
    """Radius of a sphere about the primitive's origin that contains it."""
    if kind == "sphere":
        return size[0]
    if kind == "box":
        return float(np.linalg.norm(size)) / 2
    if kind == "cylinder":
        return float(np.hypot(size[0], size[1] / 2))
    if kind == "capsule":
        return size[0] + size[1] / 2
    raise ValueError(kind)


def _shape_record(shape) -> tuple[str, tuple[float, ...]] | None:
    if isinstance(shape, Sphere):
        return "sphere", (shape.radius(),)
    if isinstance(shape, Box):
        return "box", (shape.width(), shape.depth(), shape.height())
    if isinstance(shape, Cylinder):
        return "cylinder", (shape.radius(), shape.length())
    if isinstance(shape, Capsule):
        return "capsule", (shape.radius(), shape.length())
    return None


def make_geometry_filter(
    workcell: Workcell, margin_m: float = 0.01
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """keep(points_W (N, 3), q (6,)) -> bool mask of points farther than margin_m from the robot,
    tool, rod (or turntable) and cell primitives at configuration q."""
    plant, sg = workcell.plant, workcell.scene_graph
    inspector = sg.model_inspector()
    object_frame = plant.GetBodyFrameIdOrThrow(plant.GetBodyByName(OBJECT_BODY).index())
    primitives = []
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        record = _shape_record(inspector.GetShape(gid))
        is_keep_out = inspector.GetFrameId(gid) == object_frame and record and record[0] == "sphere"
        if record is None or is_keep_out:
            continue
        primitives.append(_Primitive(record[0], record[1], gid))
    if workcell.presentation != "hanging":
        return _keep_points(workcell, primitives, margin_m)
    # The rod hangs down the vertical through the scan centre to wherever the (unknown) object
    # begins: remove that whole line, not just the part above the planner's keep-out sphere.
    c = workcell.config.object_center_m
    length = workcell.config.rod_top_z_m - c[2]
    X_WR = np.eye(4)
    X_WR[:3, 3] = (c[0], c[1], c[2] + length / 2)
    primitives.append(_Primitive("cylinder", (workcell.config.rod_radius_m, length), X_WG=X_WR))
    return _keep_points(workcell, primitives, margin_m)


def _keep_points(
    workcell: Workcell, primitives: list[_Primitive], margin_m: float
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """keep(points_W, q) over these primitives (posed by Drake at q, or fixed)."""
    plant, sg = workcell.plant, workcell.scene_graph
    context = workcell.diagram.CreateDefaultContext()
    plant_context = plant.GetMyContextFromRoot(context)
    sg_context = sg.GetMyContextFromRoot(context)
    # Views are filtered on several threads (the scan's view stream): one context, so one
    # configuration at a time; the primitives' poses are read under the lock, the points are
    # tested against them outside it.
    lock = threading.Lock()

    def poses(q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        with lock:
            plant.SetPositions(plant_context, workcell.robot, np.asarray(q, float))
            query = sg.get_query_output_port().Eval(sg_context)
            out = []
            for prim in primitives:
                if prim.X_WG is not None:
                    out.append((prim.X_WG[:3, :3], prim.X_WG[:3, 3]))
                else:
                    X_WG = query.GetPoseInWorld(prim.geometry_id)
                    out.append((X_WG.rotation().matrix(), X_WG.translation()))
            return out

    def keep(points_W: np.ndarray, q: np.ndarray) -> np.ndarray:
        points_W = np.asarray(points_W, float)
        mask = np.ones(len(points_W), bool)
        if not len(points_W):
            return mask
        # The cloud's bounding sphere: a primitive whose reach misses it has no point near it
        # (most of the arm is far from the object), and its points need no test.
        centre = 0.5 * (points_W.min(axis=0) + points_W.max(axis=0))
        radius = float(np.sqrt(np.max(np.einsum("ij,ij->i", points_W - centre, points_W - centre))))
        for prim, (R, p) in zip(primitives, poses(q), strict=True):
            # Only points within the primitive's bounding sphere (+ margin) can be too close:
            # the exact distance runs on those few (the object is far from most of the arm).
            reach = _bounding_radius(prim.kind, prim.size) + margin_m
            if np.linalg.norm(p - centre) > radius + reach + 1e-9:
                continue
            d = points_W - p
            near = np.flatnonzero(np.einsum("ij,ij->i", d, d) < reach**2)
            if len(near):
                p_GQ = (points_W[near] - p) @ R
                mask[near] &= _signed_distance(prim.kind, prim.size, p_GQ) > margin_m
        return mask

    return keep

"""Collision checking of the arm's configurations against the work cell, with Drake.

One `CollisionChecker` wraps Drake's `SceneGraphCollisionChecker` on the planner's `RobotDiagram`
(robot, camera tool, table, fence, radiator, object keep-out sphere and its rod). A configuration
is "free" when every unfiltered pair (robot-robot and robot-environment) is farther apart than
the padding. Edges q_a -> q_b are checked at configurations no more than `edge_step_rad` apart in
ANY joint (the distance is the max-norm), so no joint moves more than that between two checks.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pydrake.common import Parallelism
from pydrake.geometry import Mesh, Role
from pydrake.planning import SceneGraphCollisionChecker

from robots.models.workcell import Workcell


def _max_norm_distance(q_a: np.ndarray, q_b: np.ndarray) -> float:
    # The issue bounds the per-joint motion between checks, so the edge metric is the max-norm.
    return float(np.max(np.abs(np.asarray(q_b) - np.asarray(q_a))))


class CollisionChecker:
    """Configuration and edge checks with padding (m) around robot and tool."""

    def __init__(self, workcell: Workcell, padding_m: float, edge_step_rad: float) -> None:
        self.workcell = workcell
        self.padding_m = float(padding_m)
        self.edge_step_rad = float(edge_step_rad)
        # One context: the machine is shared, and OMPL calls us from one thread anyway.
        self._checker = SceneGraphCollisionChecker(
            model=workcell.diagram,
            robot_model_instances=[workcell.robot],
            configuration_distance_function=_max_norm_distance,
            edge_step_size=self.edge_step_rad,
            env_collision_padding=self.padding_m,
            self_collision_padding=self.padding_m,
            implicit_context_parallelism=Parallelism(1),
        )
        self.checks = 0
        self._context = None  # built on the first describe(): messages only

    def is_free(self, q: np.ndarray) -> bool:
        self.checks += 1
        return bool(self._checker.CheckConfigCollisionFree(np.asarray(q, float)))

    def are_free(self, qs: Sequence[np.ndarray] | np.ndarray) -> np.ndarray:
        """(K,) bools for K configurations, checked in one call into Drake."""
        qs = [np.asarray(q, float) for q in qs]
        self.checks += len(qs)
        if not qs:
            return np.zeros(0, bool)
        return np.asarray(self._checker.CheckConfigsCollisionFree(qs, Parallelism(1)), bool)

    def edge_free(self, q_a: np.ndarray, q_b: np.ndarray) -> bool:
        steps = math.ceil(_max_norm_distance(q_a, q_b) / self.edge_step_rad)
        self.checks += steps + 1
        return bool(
            self._checker.CheckEdgeCollisionFree(np.asarray(q_a, float), np.asarray(q_b, float))
        )

    def describe(self, q: np.ndarray, max_pairs: int = 3) -> str:
        """The closest offending geometry pairs at q, for messages ("tool vs rod at -3.0 mm")."""
        if self._context is None:
            self._context = self.workcell.diagram.CreateDefaultContext()
        plant, scene_graph = self.workcell.plant, self.workcell.scene_graph
        plant_context = plant.GetMyContextFromRoot(self._context)
        plant.SetPositions(plant_context, self.workcell.robot, np.asarray(q, float))
        query = scene_graph.get_query_output_port().Eval(
            scene_graph.GetMyContextFromRoot(self._context)
        )
        inspector = query.inspector()
        pairs = sorted(
            query.ComputeSignedDistancePairwiseClosestPoints(self.padding_m),
            key=lambda pair: pair.distance,
        )

        def name(geometry_id) -> str:
            frame = inspector.GetName(inspector.GetFrameId(geometry_id)).split("::")[-1]
            return f"{frame}/{inspector.GetName(geometry_id).split('::')[-1]}"

        hits = [
            f"{name(pair.id_A)} vs {name(pair.id_B)} at {1e3 * pair.distance:.1f} mm"
            for pair in pairs[:max_pairs]
            if pair.distance < self.padding_m
        ]
        if not hits:
            return "no pair closer than the padding"
        return f"closer than the {1e3 * self.padding_m:.0f} mm padding: " + ", ".join(hits)

    def fingerprint(self) -> str:
        """Hash of every collision geometry (shape, pose, owning body), the filters and paddings.

        Anything that changes what collides changes this, however the cell was built.
        """
        inspector = self.workcell.scene_graph.model_inspector()
        h = hashlib.sha256()
        for geometry_id in sorted(
            inspector.GetAllGeometryIds(role=Role.kProximity), key=lambda g: inspector.GetName(g)
        ):
            shape = inspector.GetShape(geometry_id)
            h.update(inspector.GetName(inspector.GetFrameId(geometry_id)).encode())
            h.update(inspector.GetName(geometry_id).encode())
            h.update(repr(shape).encode())
            if isinstance(shape, Mesh) and shape.source().is_path():
                h.update(Path(shape.source().path()).read_bytes())
            h.update(np.round(inspector.GetPoseInFrame(geometry_id).GetAsMatrix4(), 12).tobytes())
        h.update(np.asarray(self._checker.GetFilteredCollisionMatrix()).tobytes())
        h.update(np.asarray(self._checker.GetPaddingMatrix()).tobytes())
        h.update(repr(self.edge_step_rad).encode())
        return h.hexdigest()

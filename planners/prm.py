"""The multi-query roadmap: built by OMPL's PRM over Drake collision checks, cached on disk.

OMPL samples the joint-limit box, keeps collision-free milestones (Drake state check) and
connects each to its k nearest neighbours. The edges are not checked while the roadmap is built
(a lazy PRM): checking all ~10 000 of them took 28 s, a newcomer's first wait, while a scan
uses a few dozen. The roadmap is exported (vertices, edges) and kept as plain arrays: OMPL 2.0's
Python bindings cannot load a stored roadmap back into a PRM, so queries are answered here, on
exactly the graph OMPL built.

Query (lazy, so that a query pays only for the edges it uses): the start and the goal are joined
to their k nearest milestones and to each other by candidate edges; Dijkstra finds the fastest
route (edge cost: straight-line cruise time, max_i |dq_i| / v_i); every edge on it not yet
proven is checked by Drake at the planner's fine step and the failures removed until the route
is proven or none is left. Roadmap edges keep their verdict for later queries. The direct edge
is the cheapest candidate, so a free straight move is found with one edge check.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from planners.collision import CollisionChecker
from robots.arms.arm import Arm

# Bump when the stored format or the way a roadmap is built changes.
ROADMAP_FORMAT = 2
# scipy's csgraph reads an explicit zero as "no edge"; keep every real edge strictly positive.
_MIN_EDGE_COST_S = 1e-12

# OMPL logs every planner set-up and solve at INFO level on stdout; the scan's output is ours.
ou.setLogLevel(ou.LOG_WARN)


@dataclass(frozen=True, eq=False)
class Roadmap:
    """vertices_rad (N, n) collision-free milestones; edges (E, 2) vertex indices i < j, NOT
    checked (each is proven when a query first uses it); build_s the wall time OMPL spent
    building it."""

    vertices_rad: np.ndarray
    edges: np.ndarray
    build_s: float
    key: str

    def __post_init__(self) -> None:
        for name in ("vertices_rad", "edges"):
            value = np.array(getattr(self, name))
            value.setflags(write=False)
            object.__setattr__(self, name, value)


class _DeferredMotionValidator(ob.MotionValidator):
    """While the roadmap is built, every motion is accepted: queries check the edges they use."""

    def checkMotion(self, a, b) -> bool:  # noqa: N802 (OMPL's name)
        return True


class _DrakeMotionValidator(ob.MotionValidator):
    """OMPL asks whether the straight motion a -> b is valid; Drake answers at fine steps."""

    def __init__(self, si: ob.SpaceInformation, checker: CollisionChecker, joints: int) -> None:
        super().__init__(si)
        self._checker = checker
        self._joints = joints

    def checkMotion(self, a, b) -> bool:  # noqa: N802 (OMPL's name)
        n = self._joints
        return self._checker.edge_free(state_to_array(a, n), state_to_array(b, n))


def state_to_array(state, joints: int) -> np.ndarray:
    return np.array([state[i] for i in range(joints)])


def _fill_state(state, q: np.ndarray):
    for i, value in enumerate(q):
        state[i] = float(value)
    return state


class OmplSpace:
    """The arm's joint-limit box as an OMPL state space, validity and motions checked by Drake."""

    def __init__(self, arm: Arm, checker: CollisionChecker) -> None:
        self.joints = n = arm.joint_count
        self.space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        for i, (lo, hi) in enumerate(zip(arm.lower.tolist(), arm.upper.tolist())):
            bounds.setLow(i, lo)
            bounds.setHigh(i, hi)
        self.space.setBounds(bounds)
        self.si = ob.SpaceInformation(self.space)
        # OMPL's validity callback must return a Python bool (numpy.bool_ raises bad_cast).
        self.si.setStateValidityChecker(lambda s: checker.is_free(state_to_array(s, n)))
        self.motion_validator = _DrakeMotionValidator(self.si, checker, n)
        self.si.setMotionValidator(self.motion_validator)
        self.si.setup()

    def state(self, q: np.ndarray):
        return _fill_state(self.si.allocState(), q)

    def array(self, state) -> np.ndarray:
        return state_to_array(state, self.joints)

    def path(self, waypoints: list[np.ndarray]) -> og.PathGeometric:
        path = og.PathGeometric(self.si)
        for q in waypoints:
            path.append(self.state(q))
        return path


_OMPL_SEED: list[int] = []


def seed_ompl(seed: int) -> None:
    """Seed OMPL's process-wide generator (OMPL accepts a seed only before its first random
    number, so only the first planner of a process sets it; later calls are no-ops)."""
    if not _OMPL_SEED:
        ou.RNG.setSeed(seed)
        _OMPL_SEED.append(seed)


def build_roadmap(
    space: OmplSpace, milestones: int, neighbours: int, max_time_s: float, key: str
) -> Roadmap:
    """Grow OMPL's PRM until it has `milestones` vertices or `max_time_s` has passed; its edges
    are left unchecked (see the module docstring)."""
    deferred = _DeferredMotionValidator(space.si)
    space.si.setMotionValidator(deferred)
    try:
        prm = og.PRM(space.si)
        prm.setMaxNearestNeighbors(neighbours)
        prm.setProblemDefinition(ob.ProblemDefinition(space.si))
        prm.setup()
        start = time.perf_counter()
        enough = ob.PlannerTerminationCondition(lambda: prm.milestoneCount() >= milestones)
        ptc = ob.plannerOrTerminationCondition(
            enough, ob.timedPlannerTerminationCondition(max_time_s)
        )
        prm.constructRoadmap(ptc)
        build_s = time.perf_counter() - start
    finally:
        # RRTConnect and everything else checks motions with Drake again.
        space.si.setMotionValidator(space.motion_validator)
    data = ob.PlannerData(space.si)
    prm.getPlannerData(data)
    n = data.numVertices()
    vertices = np.array([space.array(data.getVertex(i).getState()) for i in range(n)])
    edges = {(min(i, j), max(i, j)) for i in range(n) for j in data.getEdges(i)}
    edge_array = np.array(sorted(edges), dtype=np.int64).reshape(-1, 2)
    return Roadmap(vertices.reshape(-1, space.joints), edge_array, build_s, key)


# --- cache -----------------------------------------------------------------------------------


def cache_key(parts: dict[str, str]) -> str:
    """sha256 over named parts (sorted), so that the key says nothing but 'same inputs'."""
    text = json.dumps({"format": ROADMAP_FORMAT, **parts}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def cache_path(cache_dir: Path, key: str) -> Path:
    return Path(cache_dir) / f"roadmap-{key[:32]}.npz"


def load_roadmap(cache_dir: Path, key: str, joints: int) -> Roadmap | None:
    """The cached roadmap for this key over `joints` joints, or None (absent, damaged, or
    written for another key)."""
    path = cache_path(cache_dir, key)
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            vertices, edges = data["vertices_rad"], data["edges"]
            build_s = float(data["build_s"])
    except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile):
        return None
    well_formed = (
        vertices.ndim == 2
        and vertices.shape[1] == joints
        and np.all(np.isfinite(vertices))
        and edges.ndim == 2
        and edges.shape[1] == 2
        and (edges.size == 0 or (edges.min() >= 0 and edges.max() < len(vertices)))
    )
    return Roadmap(vertices, edges, build_s, key) if well_formed else None


def save_roadmap(cache_dir: Path, roadmap: Roadmap) -> Path:
    """Write atomically: a reader sees the old file, or the whole new one, never a part."""
    cache_dir = Path(cache_dir)
    cache_dir.mkdir(parents=True, exist_ok=True)
    final = cache_path(cache_dir, roadmap.key)
    fd, tmp = tempfile.mkstemp(dir=cache_dir, prefix=".roadmap-", suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(
                f,
                vertices_rad=roadmap.vertices_rad,
                edges=roadmap.edges,
                build_s=roadmap.build_s,
                key=roadmap.key,
            )
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, final)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return final


# --- queries ---------------------------------------------------------------------------------


def cruise_time_s(q_a: np.ndarray, q_b: np.ndarray, velocity_rad_s: np.ndarray) -> np.ndarray:
    """Edge cost: time at full speed of the slowest joint, (..., n) -> (...)."""
    return np.max(np.abs(np.asarray(q_b) - np.asarray(q_a)) / velocity_rad_s, axis=-1)


class RoadmapGraph:
    """The roadmap as a weighted graph with a nearest-neighbour index, ready for queries."""

    def __init__(self, roadmap: Roadmap, velocity_rad_s: np.ndarray) -> None:
        self.roadmap = roadmap
        self.velocity_rad_s = np.asarray(velocity_rad_s, float)
        v = roadmap.vertices_rad
        self.n = len(v)
        i, j = roadmap.edges[:, 0], roadmap.edges[:, 1]
        self._weights = np.maximum(cruise_time_s(v[i], v[j], self.velocity_rad_s), _MIN_EDGE_COST_S)
        # Verdicts of the roadmap's edges, kept across queries: True proven, False blocked.
        self._index = {(int(a), int(b)): k for k, (a, b) in enumerate(roadmap.edges)}
        self._proven = np.zeros(len(roadmap.edges), bool)
        self._alive = np.ones(len(roadmap.edges), bool)
        # In scaled coordinates q / v, the max-norm distance is exactly the edge cost.
        self._tree = cKDTree(v / self.velocity_rad_s) if self.n else None

    def nearest(self, q: np.ndarray, k: int) -> np.ndarray:
        if self._tree is None:
            return np.zeros(0, int)
        k = min(k, self.n)
        _, idx = self._tree.query(np.asarray(q) / self.velocity_rad_s, k=k, p=np.inf)
        return np.atleast_1d(idx)

    def query(
        self,
        q_start: np.ndarray,
        q_goal: np.ndarray,
        neighbours: int,
        edge_free: Callable[[np.ndarray, np.ndarray], bool],
        max_edge_checks: int,
    ) -> list[np.ndarray] | None:
        """Waypoints start ... goal over proven edges, or None when none is found."""
        s, g = self.n, self.n + 1
        points = {s: np.asarray(q_start, float), g: np.asarray(q_goal, float)}
        candidates: dict[tuple[int, int], float] = {}
        for a, q in ((s, q_start), (g, q_goal)):
            for m in self.nearest(q, neighbours):
                candidates[(a, int(m))] = float(
                    cruise_time_s(q, self.roadmap.vertices_rad[m], self.velocity_rad_s)
                )
        candidates[(s, g)] = float(cruise_time_s(q_start, q_goal, self.velocity_rad_s))
        proven: set[tuple[int, int]] = set()
        checks = 0
        while candidates and checks < max_edge_checks:
            route = self._shortest(candidates)
            if route is None:
                return None
            for edge in zip(route[:-1], route[1:]):
                key = _candidate_key(edge, candidates)
                if key is None:
                    k = self._index[(min(edge), max(edge))]
                    if self._proven[k]:
                        continue
                elif key in proven:
                    continue
                checks += 1
                ends = [points[e] if e >= self.n else self.roadmap.vertices_rad[e] for e in edge]
                free = edge_free(ends[0], ends[1])
                if key is None:
                    self._proven[k], self._alive[k] = free, free
                elif free:
                    proven.add(key)
                else:
                    del candidates[key]
                if not free:
                    break
            else:
                return [
                    points[node] if node >= self.n else self.roadmap.vertices_rad[node]
                    for node in route
                ]
        return None

    def _shortest(self, candidates: dict[tuple[int, int], float]) -> list[int] | None:
        pairs = np.array(list(candidates.keys()), dtype=np.int64).reshape(-1, 2)
        costs = np.maximum(np.array(list(candidates.values())), _MIN_EDGE_COST_S)
        edges, w = self.roadmap.edges[self._alive], self._weights[self._alive]
        rows = np.concatenate([edges[:, 0], edges[:, 1], pairs[:, 0], pairs[:, 1]])
        cols = np.concatenate([edges[:, 1], edges[:, 0], pairs[:, 1], pairs[:, 0]])
        weights = np.concatenate([w, w, costs, costs])
        graph = csr_matrix((weights, (rows, cols)), shape=(self.n + 2, self.n + 2))
        s, g = self.n, self.n + 1
        dist, pred = dijkstra(graph, indices=s, return_predecessors=True)
        if not np.isfinite(dist[g]):
            return None
        route = [g]
        while route[-1] != s:
            route.append(int(pred[route[-1]]))
        return route[::-1]


def _candidate_key(
    edge: tuple[int, int], candidates: dict[tuple[int, int], float]
) -> tuple[int, int] | None:
    """The candidate edge (to the start or goal) this route step uses, or None for a roadmap
    edge."""
    a, b = edge
    if (a, b) in candidates:
        return (a, b)
    if (b, a) in candidates:
        return (b, a)
    return None


def solve_rrtconnect(
    space: OmplSpace, q_start: np.ndarray, q_goal: np.ndarray, max_time_s: float
) -> list[np.ndarray] | None:
    """OMPL RRTConnect from scratch (no roadmap): waypoints or None within the time budget."""
    pdef = ob.ProblemDefinition(space.si)
    pdef.setStartAndGoalStates(space.state(q_start), space.state(q_goal))
    planner = og.RRTConnect(space.si)
    planner.setProblemDefinition(pdef)
    planner.setup()
    status = planner.solve(max_time_s)
    if status.getStatus() != ob.PlannerStatus.EXACT_SOLUTION:
        return None
    path = pdef.getSolutionPath()
    return [space.array(s) for s in path.getStates()]


def shortcut(space: OmplSpace, waypoints: list[np.ndarray], max_steps: int) -> list[np.ndarray]:
    """OMPL's vertex reduction and partial shortcutting (max_steps attempts per pass); start and
    goal stay exactly as given."""
    if len(waypoints) <= 2:
        return waypoints
    path = space.path(waypoints)
    simplifier = og.PathSimplifier(space.si)
    # Bounded passes: OMPL's full simplify() gave ~13 % shorter motions on roadmap routes but
    # cost ~180 ms per query here (every attempt is a fine-grained Drake edge check).
    simplifier.reduceVertices(path, max_steps)
    if path.getStateCount() > 2:
        simplifier.partialShortcutPath(path, max_steps)
        simplifier.reduceVertices(path, max_steps)
    out = [space.array(s) for s in path.getStates()]
    out[0], out[-1] = np.asarray(waypoints[0], float), np.asarray(waypoints[-1], float)
    return out

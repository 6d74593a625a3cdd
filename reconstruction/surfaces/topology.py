"""Triangle-mesh topology: edges, boundary loops, manifoldness, and the repairs the surfaces get
(debris and degenerate faces removed, holes below the data's resolution closed)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


@dataclass(frozen=True)
class MeshQuality:
    """Topology of a mesh: an edge used by one triangle is a boundary (hole or rim) edge."""

    n_vertices: int
    n_triangles: int
    n_components: int
    boundary_edges: int
    non_manifold_edges: int
    watertight: bool
    area_m2: float
    # Perimeters (m) of the closed loops of boundary edges, longest first: the rim of the
    # observed region, then any holes.
    boundary_loops_m: tuple[float, ...]


def clean_mesh(mesh: o3d.geometry.TriangleMesh, min_component_fraction: float) -> None:
    """In place: degenerate and duplicated faces, non-manifold edges, and small components."""
    mesh.remove_degenerate_triangles()
    mesh.remove_duplicated_triangles()
    mesh.remove_duplicated_vertices()
    if len(mesh.triangles):
        triangles = np.asarray(mesh.triangles)
        keep = _manifold_edges_keep(np.asarray(mesh.vertices), triangles)
        if not keep.all():
            mesh.remove_triangles_by_mask(~keep)
        labels, counts = triangle_components(np.asarray(mesh.triangles))
        small = counts < min_component_fraction * counts.max()
        mesh.remove_triangles_by_mask(small[labels])
    mesh.remove_unreferenced_vertices()


def canonical_order(mesh: o3d.geometry.TriangleMesh) -> o3d.geometry.TriangleMesh:
    """The same mesh with its vertices sorted by coordinates and its triangles by vertex
    index (each turned, not flipped, to start at its smallest index): one order for one
    geometry. Open3D's TSDF extraction lists vertices in its parallel hash map's order, which
    changes from run to run and with the number of threads."""
    v = np.asarray(mesh.vertices)
    order = np.lexsort(v.T[::-1])
    new_index = np.empty_like(order)
    new_index[order] = np.arange(len(order))
    t = new_index[np.asarray(mesh.triangles)]
    first = np.argmin(t, axis=1)
    t = np.stack([t[np.arange(len(t)), (first + k) % 3] for k in range(3)], axis=1)
    t = t[np.lexsort(t.T[::-1])]
    out = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v[order]), o3d.utility.Vector3iVector(t.astype(np.int32))
    )
    if mesh.has_vertex_colors():
        out.vertex_colors = o3d.utility.Vector3dVector(np.asarray(mesh.vertex_colors)[order])
    return out


def _manifold_edges_keep(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Keep mask that leaves every edge in at most two triangles, dropping the smallest ones
    of an overused edge first (Open3D's `remove_non_manifold_edges` rule; it took 2.8 s on a
    600k-triangle Poisson mesh with 74 such edges, this takes a fraction of a second)."""
    use = _edge_use(triangles)
    keep = np.ones(len(triangles), bool)
    overused = np.flatnonzero(use.uses > 2)
    if not len(overused):
        return keep
    t = triangles
    area = np.linalg.norm(
        np.cross(vertices[t[:, 1]] - vertices[t[:, 0]], vertices[t[:, 2]] - vertices[t[:, 0]]),
        axis=1,
    )
    hit = np.isin(use.of_triangle, overused)
    rows, cols = np.nonzero(hit)
    edge_ids = use.of_triangle[rows, cols]
    for edge in overused:
        on_edge = rows[edge_ids == edge]
        on_edge = on_edge[keep[on_edge]]
        if len(on_edge) > 2:
            keep[on_edge[np.argsort(area[on_edge], kind="stable")[: len(on_edge) - 2]]] = False
    return keep


def kept_triangles(
    vertices: np.ndarray, triangles: np.ndarray, keep: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The triangles where `keep` (M,) bool, and only the vertices they use, in their order
    (Open3D's `remove_unreferenced_vertices` on arrays)."""
    triangles = triangles[keep]
    used = np.zeros(len(vertices), bool)
    used[triangles] = True
    new_index = np.cumsum(used) - 1
    return vertices[used], new_index[triangles]


def triangle_components(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of triangles sharing an edge: a label per triangle (M,) and the
    triangle count of each component. (Open3D's `cluster_connected_triangles` gives the same
    partition several times slower.)"""
    m = len(triangles)
    if not m:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    edge_of = _edge_use(triangles).of_triangle
    # Triangles and edges as the nodes of one graph, each triangle joined to its three edges.
    rows = np.repeat(np.arange(m), 3)
    n = m + int(edge_of.max()) + 1
    graph = coo_matrix((np.ones(3 * m), (rows, m + edge_of.ravel())), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    _, labels = np.unique(label[:m], return_inverse=True)
    return labels, np.bincount(labels)


@dataclass(frozen=True, eq=False)
class _EdgeUse:
    """The distinct edges of a triangle mesh (K, 2), how many triangles use each (K,), and the
    distinct edge of each triangle's three edges (M, 3)."""

    edges: np.ndarray
    uses: np.ndarray
    of_triangle: np.ndarray


# Per thread (surfaces are built on several at once), the last triangles given to `_edge_use`
# and their table: finishing a mesh asks for the table of the same triangles up to five times
# in a row (cleaning, then each filler looking for what is left open), 80 ms each at 300k
# triangles, where comparing the triangles takes 1 ms.
_last_edge_use = threading.local()


def _edge_use(triangles: np.ndarray) -> _EdgeUse:
    triangles = np.asarray(triangles)
    last = getattr(_last_edge_use, "entry", None)
    if last is not None and np.array_equal(last[0], triangles):
        return last[1]
    use = _edge_table(triangles)
    for table in (use.edges, use.uses, use.of_triangle):
        table.flags.writeable = False  # shared by the callers that ask again
    _last_edge_use.entry = (triangles.copy(), use)
    return use


def _edge_table(triangles: np.ndarray) -> _EdgeUse:
    t = np.sort(np.asarray(triangles, np.int64), axis=1)
    pairs = np.stack([t[:, [0, 1]], t[:, [1, 2]], t[:, [0, 2]]], axis=1).reshape(-1, 2)
    n = int(t.max()) + 1 if len(t) else 1
    # One integer per edge: np.unique on a 1-D key is ~20x faster than on rows.
    keys, inverse, uses = np.unique(
        pairs[:, 0] * n + pairs[:, 1], return_inverse=True, return_counts=True
    )
    return _EdgeUse(np.stack([keys // n, keys % n], axis=1), uses, inverse.reshape(-1, 3))


def _boundary_loop_count(mesh: o3d.geometry.TriangleMesh) -> int:
    use = _edge_use(mesh.triangles)
    return len(_boundary_loops(np.asarray(mesh.vertices), use.edges[use.uses == 1]))


def _manifold_patches(triangles: np.ndarray, added: np.ndarray) -> np.ndarray:
    """Mask of the `added` triangles to keep: each connected patch of added triangles (one
    filled hole) is dropped whole when one of its edges ends up in more than two triangles,
    which happens where the hole touched another boundary."""
    use = _edge_use(triangles)
    edge_of, uses = use.of_triangle, use.uses
    index = np.flatnonzero(added)
    # Added triangles sharing an edge belong to the same patch.
    rows = np.repeat(np.arange(len(index)), 3)
    incidence = coo_matrix(
        (np.ones(len(rows)), (rows, edge_of[index].ravel())), shape=(len(index), len(uses))
    ).tocsr()
    _, patch = connected_components(incidence @ incidence.T, directed=False)
    bad = np.zeros(patch.max() + 1 if len(patch) else 0, bool)
    np.logical_or.at(bad, patch, (uses[edge_of[index]] > 2).any(axis=1))
    keep = np.ones(len(triangles), bool)
    keep[index] = ~bad[patch]
    return keep


def fill_small_holes(mesh: o3d.geometry.TriangleMesh, max_radius_m: float) -> int:
    """In place: close the holes whose boundary fits in a sphere of max_radius_m (Open3D's
    fill_holes, VTK's hole filler) unless closing one would make the mesh non-manifold.
    Returns how many holes were closed."""
    if max_radius_m <= 0 or not len(mesh.triangles):
        return 0
    before = _boundary_loop_count(mesh)
    vertices = np.asarray(mesh.vertices)
    triangles = _vtk_fill(vertices, np.asarray(mesh.triangles), max_radius_m)
    triangles = _fan_fill(vertices, triangles, max_radius_m)
    triangles = _reopen_pinches(vertices, triangles, max_radius_m)
    mesh.triangles = o3d.utility.Vector3iVector(triangles)
    return before - _boundary_loop_count(mesh)


def _vtk_fill(
    vertices: np.ndarray,
    triangles: np.ndarray,
    max_radius_m: float,
    within: np.ndarray | None = None,
) -> np.ndarray:
    """The triangles with VTK's patches of the holes up to max_radius_m, each patch kept only
    when it leaves every edge manifold (and, with `within`, a vertex mask, when all its
    vertices are in it)."""
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
    )
    # fill_holes hands the mesh to VTK without copying: the tensor mesh must stay alive until
    # the result is copied back (a temporary gave garbage vertices).
    tensor_mesh = o3d.t.geometry.TriangleMesh.from_legacy(mesh)
    closed = tensor_mesh.fill_holes(hole_size=max_radius_m).to_legacy()
    del tensor_mesh
    # VTK works in float32 and only adds triangles between existing boundary vertices: keep
    # our float64 vertices (and colours) and take its triangles.
    if len(closed.vertices) != len(vertices) or not np.allclose(
        np.asarray(closed.vertices), vertices, rtol=0, atol=1e-6
    ):
        raise RuntimeError("fill_holes moved or added vertices")
    filled = np.asarray(closed.triangles)
    # VTK appends the new triangles after the existing ones.
    if not np.array_equal(filled[: len(triangles)], triangles):
        raise RuntimeError("fill_holes changed the existing triangles")
    added = np.arange(len(filled)) >= len(triangles)
    if within is not None:
        outside = added & ~within[filled].all(axis=1)
        filled, added = filled[~outside], added[~outside]
    if added.any():
        filled = filled[_manifold_patches(filled, added)]
    return filled


def _loop_labels(n_vertices: int, boundary: np.ndarray) -> np.ndarray:
    """Per vertex, the label of the boundary loop (connected boundary edges) it is on."""
    n = n_vertices
    graph = coo_matrix((np.ones(len(boundary)), (boundary[:, 0], boundary[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _small_loops(vertices: np.ndarray, triangles: np.ndarray, max_radius_m: float) -> list:
    """The boundary loops (each its (K, 2) edges) that fit in a sphere of max_radius_m."""
    use = _edge_use(triangles)
    boundary = use.edges[use.uses == 1]
    if not len(boundary):
        return []
    label = _loop_labels(len(vertices), boundary)
    loops = []
    for loop_label in np.unique(label[boundary[:, 0]]):
        edges = boundary[label[boundary[:, 0]] == loop_label]
        points = vertices[np.unique(edges)]
        if np.linalg.norm(points - points.mean(axis=0), axis=1).max() <= max_radius_m:
            loops.append(edges)
    return loops


def _reopen_pinches(
    vertices: np.ndarray, triangles: np.ndarray, max_radius_m: float, rounds: int = 3
) -> np.ndarray:
    """Small holes neither filler could close: their rim is pinched (a vertex where two fans
    of the surface touch, so every patch would reuse an existing edge; Poisson leaves these
    where thin sheets meet). The triangles touching the rim go and the wider hole is filled
    again, within that spot only, a ring wider each round; if it still cannot be closed,
    nothing changes."""
    loops = _small_loops(vertices, triangles, max_radius_m)
    spot = np.zeros(len(vertices), bool)
    current = triangles
    for k in range(1, rounds + 1):
        if not loops:
            return current
        rim = np.zeros(len(vertices), bool)
        rim[np.concatenate([np.unique(e) for e in loops])] = True
        touching = rim[current].any(axis=1)
        spot[current[touching].ravel()] = True
        # Each removed ring is about one Poisson cell, the size of the holes themselves.
        wider = (1 + k) * max_radius_m
        current = _vtk_fill(vertices, current[~touching], wider, within=spot)
        current = _fan_fill(vertices, current, wider, within=spot)
        loops = [e for e in _small_loops(vertices, current, wider) if spot[e].all()]
    return triangles if loops else current


def _loop_order(boundary: np.ndarray) -> list[int] | None:
    """The vertices of one boundary loop in order, or None unless it is a simple cycle."""
    neighbours: dict[int, list[int]] = {}
    for a, b in boundary:
        neighbours.setdefault(int(a), []).append(int(b))
        neighbours.setdefault(int(b), []).append(int(a))
    if any(len(n) != 2 for n in neighbours.values()):
        return None
    start = int(boundary[0, 0])
    order, previous = [start], None
    while True:
        a, b = neighbours[order[-1]]
        following = b if a == previous else a
        if following == start:
            break
        previous = order[-1]
        order.append(following)
    return order if len(order) == len(neighbours) else None


def _fan_fill(
    vertices: np.ndarray,
    triangles: np.ndarray,
    max_radius_m: float,
    within: np.ndarray | None = None,
) -> np.ndarray:
    """Small holes VTK's filler left (its patch would have made an edge non-manifold: a
    diagonal of the hole already exists elsewhere) closed by a fan from the loop vertex whose
    diagonals are all new, oriented like the loop's own triangles. `within`: a vertex mask;
    only loops all in it."""
    use = _edge_use(triangles)
    n = len(vertices)
    loops = _small_loops(vertices, triangles, max_radius_m)
    if within is not None:
        loops = [e for e in loops if within[e].all()]
    if not loops:
        return triangles
    # Only edges and triangles among the small loops' vertices matter below: sets of those
    # (not of the whole mesh) keep this cheap on large meshes.
    near = np.zeros(n, bool)
    near[np.concatenate([np.unique(e) for e in loops])] = True
    existing = {(int(a), int(b)) for a, b in use.edges[near[use.edges].all(axis=1)]}
    directed = {
        (int(t[i]), int(t[(i + 1) % 3]))
        for t in triangles[near[triangles].any(axis=1)]
        for i in range(3)
    }
    added = []
    for edges in loops:
        order = _loop_order(edges)
        if order is None or len(order) < 3:
            continue
        # The mesh's triangles run along a boundary edge one way; the patch runs it the other
        # (by majority: Poisson meshes are not always consistently oriented).
        along = sum((order[i - 1], order[i]) in directed for i in range(len(order)))
        if 2 * along > len(order):
            order = order[::-1]
        for k in range(len(order)):
            apex, ring = order[k], order[k + 1 :] + order[:k]
            diagonals = [tuple(sorted((apex, v))) for v in ring[1:-1]]
            if any(d in existing for d in diagonals):
                continue
            added += [(apex, ring[i], ring[i + 1]) for i in range(len(ring) - 1)]
            existing.update(diagonals)
            break
    if not added:
        return triangles
    return np.vstack([triangles, np.array(added, triangles.dtype)])


def mesh_quality(mesh) -> MeshQuality:
    """Topology of any mesh with `vertices` (V, 3) and `triangles` (M, 3) arrays."""
    tris = np.asarray(mesh.triangles)
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.array(mesh.vertices, np.float64)),
        o3d.utility.Vector3iVector(np.array(tris, np.int32)),
    )
    use = _edge_use(tris)
    uses = use.uses
    n_components = len(triangle_components(tris)[1])
    return MeshQuality(
        len(mesh.vertices),
        len(mesh.triangles),
        n_components,
        int(np.sum(uses == 1)),
        int(np.sum(uses > 2)),
        bool(len(tris) and np.all(uses == 2) and m.is_vertex_manifold()),
        float(m.get_surface_area()) if len(tris) else 0.0,
        _boundary_loops(np.asarray(mesh.vertices), use.edges[uses == 1]),
    )


def _boundary_loops(vertices: np.ndarray, boundary: np.ndarray) -> tuple[float, ...]:
    if not len(boundary):
        return ()
    label = _loop_labels(len(vertices), boundary)
    length = np.linalg.norm(vertices[boundary[:, 0]] - vertices[boundary[:, 1]], axis=1)
    perimeter = np.bincount(label[boundary[:, 0]], weights=length)
    return tuple(float(p) for p in sorted(perimeter[perimeter > 0], reverse=True))

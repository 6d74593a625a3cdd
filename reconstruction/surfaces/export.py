"""Meshes as CAD and printing users want them: in millimetres or metres, in the world frame W or
in an object frame O (centred on the surface, along its principal axes), optionally decimated
with a guaranteed bound on the geometric error it made.

The exported file's coordinates p_file relate to the world in metres by
    p_W = X_WO @ [p_file / units_per_m, 1]
with X_WO (metres) written beside the files; for the world frame X_WO is the identity.

The decimation error is the symmetric Hausdorff distance between the full and the decimated
mesh, reported as an upper bound (not a sample estimate, which can only under-state it): every
triangle is cut into cells and each cell's distance to the other mesh bounded from above by the
distance of its corners to one triangle of the other mesh (the distance to a triangle is convex,
so over a cell it is largest at a corner). Cells whose bound exceeds the best estimate by more
than a tolerance are split until it holds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import open3d as o3d

from reconstruction.common.checks import check_fields, positive, require_choice, require_count
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose, transform_points
from reconstruction.surfaces.meshes import SurfaceMesh
from reconstruction.surfaces.topology import mesh_quality

# File units per metre.
UNITS_PER_M = {"m": 1.0, "mm": 1000.0}
EXPORT_FRAMES = ("world", "object")
# The smallest closed triangle mesh (a tetrahedron).
MIN_DECIMATE_TRIANGLES = 4
# Far above any mesh of this scanner (~1M triangles at Poisson depth 8): a larger value is a typo.
MAX_DECIMATE_TRIANGLES = 100_000_000


@dataclass(frozen=True)
class MeshExportConfig:
    """How meshes are written (`processing.mesh_export`); the defaults write what the
    reconstruction made (metres, world frame, every triangle)."""

    units: str = "m"
    frame: str = "world"
    # At most this many triangles per mesh file (quadric decimation); None: no decimation.
    decimate_triangles: int | None = None
    # The reported Hausdorff bound exceeds the largest distance found by at most this much
    # (cells are split until it holds); 20 um is 1/50 of the fused cloud's 1 mm spacing.
    hausdorff_tolerance_m: float = positive(2e-5)

    def __post_init__(self) -> None:
        require_choice("mesh_export", "units", self.units, UNITS_PER_M)
        require_choice("mesh_export", "frame", self.frame, EXPORT_FRAMES)
        if self.decimate_triangles is not None:
            require_count(
                "mesh_export",
                self,
                ["decimate_triangles"],
                minimum=MIN_DECIMATE_TRIANGLES,
                maximum=MAX_DECIMATE_TRIANGLES,
            )
        check_fields("mesh_export", self)


@dataclass(frozen=True)
class HausdorffBound:
    """Symmetric Hausdorff distance between two meshes (m): `bound_m` is a guaranteed upper
    bound, `found_m` the largest distance actually found (a lower estimate); each direction's
    bound too (full -> decimated, decimated -> full)."""

    bound_m: float
    found_m: float
    a_to_b_m: float
    b_to_a_m: float


@dataclass(frozen=True, eq=False)
class ExportedMesh:
    """One mesh ready for its files: `mesh` in frame O, coordinates in the export unit."""

    name: str
    mesh: SurfaceMesh
    triangles_full: int
    watertight_full: bool
    watertight: bool
    hausdorff: HausdorffBound | None  # None without decimation


@dataclass(frozen=True, eq=False)
class MeshExports:
    """Every mesh of a result in one export frame O and unit (X_WO in metres)."""

    X_WO: np.ndarray
    config: MeshExportConfig
    reference: str | None  # the mesh whose principal axes define O (object frame)
    meshes: tuple[ExportedMesh, ...]

    def file_stem(self, name: str) -> str:
        return export_file_stem(name, self.config)


def export_file_stem(name: str, config: MeshExportConfig) -> str:
    """mesh_<name>[_object][_mm]: a file not in world metres says so in its name, so that a
    reader expecting mesh_poisson.ply never reads millimetres as metres."""
    stem = f"mesh_{name}"
    if config.frame != "world":
        stem += f"_{config.frame}"
    if config.units != "m":
        stem += f"_{config.units}"
    return stem


def _surface_moments(vertices: np.ndarray, triangles: np.ndarray):
    """Area-weighted centroid (3,) and covariance (3, 3) of the surface (m, m^2), and each
    triangle's area and centroid: surface integrals, so that the frame does not depend on
    where the mesher put more vertices."""
    v = np.asarray(vertices, float)
    t = np.asarray(triangles, np.int64)
    # Relative to the vertex mean: the moments of a 0.2 m object 1 m from the origin would
    # otherwise lose digits to cancellation.
    shift = v.mean(axis=0)
    a, b, c = v[t[:, 0]] - shift, v[t[:, 1]] - shift, v[t[:, 2]] - shift
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = area.sum()
    if not total > 0:
        raise ScannerError("mesh export: the mesh has no area, so it has no principal axes")
    s = a + b + c
    centroid = (area[:, None] * s).sum(axis=0) / (3 * total)
    # Exact second moment of a triangle: A/12 (aa' + bb' + cc' + ss').
    second = np.einsum("k,ki,kj->ij", area, a, a)
    second += np.einsum("k,ki,kj->ij", area, b, b)
    second += np.einsum("k,ki,kj->ij", area, c, c)
    second += np.einsum("k,ki,kj->ij", area, s, s)
    covariance = second / (12 * total) - np.outer(centroid, centroid)
    return centroid + shift, covariance, area, s / 3 + shift


def principal_frame(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """X_WO of the object frame of a mesh in W: origin at the surface's area centroid, x along
    the axis of largest spread, z of least, right-handed. Each axis's sign puts the surface's
    third moment (skewness) along it positive, so the frame follows the object, not the order
    of its vertices; for a symmetric object, where that moment vanishes, the axis points to
    positive world coordinates (its largest component positive)."""
    p_WO, covariance, area, centres = _surface_moments(vertices, triangles)
    _, vectors = np.linalg.eigh(covariance)  # ascending eigenvalues
    R_WO = vectors[:, ::-1].copy()
    d = centres - p_WO
    scale = np.sqrt(max(float(np.trace(covariance)), 1e-300))
    for k in (0, 1):
        axis = R_WO[:, k]
        skew = float(area @ (d @ axis) ** 3) / (area.sum() * scale**3)
        # 1e-6: moments of a symmetric mesh cancel to ~1e-12 relative; real shapes are far
        # above 1e-6.
        sign = np.sign(skew) if abs(skew) > 1e-6 else np.sign(axis[np.argmax(np.abs(axis))])
        R_WO[:, k] = axis * (sign or 1.0)
    R_WO[:, 2] = np.cross(R_WO[:, 0], R_WO[:, 1])
    return make_pose(R_WO, p_WO)


def export_frame(mesh: SurfaceMesh, frame: str) -> np.ndarray:
    """X_WO for the export frame named `frame` (world: the identity)."""
    require_choice("mesh_export", "frame", frame, EXPORT_FRAMES)
    if frame == "world":
        return np.eye(4)
    return principal_frame(mesh.vertices, mesh.triangles)


def to_export_coordinates(mesh: SurfaceMesh, X_WO: np.ndarray, units: str) -> SurfaceMesh:
    """The mesh with vertices p_O in the export unit (same triangles and colours)."""
    p_O = transform_points(invert(X_WO), np.asarray(mesh.vertices, float))
    return SurfaceMesh(
        mesh.name,
        p_O * UNITS_PER_M[units],
        mesh.triangles,
        mesh.colors,
        mesh.filled_holes,
        mesh.filled_area_m2,
    )


def from_export_coordinates(vertices: np.ndarray, X_WO: np.ndarray, units: str) -> np.ndarray:
    """p_W (N, 3) metres of vertices read from an exported file."""
    return transform_points(X_WO, np.asarray(vertices, float) / UNITS_PER_M[units])


def decimate(mesh: SurfaceMesh, max_triangles: int) -> SurfaceMesh:
    """Quadric decimation (Garland and Heckbert, Open3D) to at most `max_triangles`; a mesh
    already that small is returned as it is. Open3D does not promise to reach its target, so
    the target is lowered in proportion until the result fits."""
    if len(mesh.triangles) <= max_triangles:
        return mesh
    source = mesh.to_open3d()
    target = max_triangles
    for _ in range(8):
        out = source.simplify_quadric_decimation(target)
        out.remove_degenerate_triangles()
        out.remove_unreferenced_vertices()
        n = len(out.triangles)
        if n <= max_triangles:
            break
        target = max(1, int(target * max_triangles / n) - 1)
    else:
        raise ScannerError(
            f"mesh export: could not decimate {mesh.name} to {max_triangles} triangles "
            f"(got {n}); give a larger decimate_triangles"
        )
    colors = None
    if mesh.colors is not None and out.has_vertex_colors():
        colors = np.clip(np.round(np.asarray(out.vertex_colors) * 255), 0, 255).astype(np.uint8)
    return SurfaceMesh(
        mesh.name,
        np.asarray(out.vertices).copy(),
        np.asarray(out.triangles).copy(),
        colors,
        mesh.filled_holes,
        mesh.filled_area_m2,
    )


def point_triangle_distances(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> np.ndarray:
    """Exact distance (m) from each point p[i] to the triangle (a[i], b[i], c[i]); all (N, 3).
    Closest-point regions after Ericson, Real-Time Collision Detection, 5.1.5. A degenerate
    triangle gets the distance to its nearest corner (an upper bound, which is what the
    Hausdorff bound needs)."""
    ab, ac = b - a, c - a

    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        q = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        q = np.where(on_bc[:, None], b + (c - b) * w_bc[:, None], q)
        on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        q = np.where(on_ac[:, None], a + ac * (d2 / (d2 - d6))[:, None], q)
        q = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, q)
        on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        q = np.where(on_ab[:, None], a + ab * (d1 / (d1 - d3))[:, None], q)
        q = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, q)
        q = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, q)
    dist = np.linalg.norm(p - q, axis=1)
    corner = np.minimum(np.linalg.norm(ap, axis=1), np.linalg.norm(bp, axis=1))
    corner = np.minimum(corner, np.linalg.norm(cp, axis=1))
    bad = ~np.isfinite(dist)
    dist[bad] = corner[bad]
    return np.minimum(dist, corner)


class _NearestTriangles:
    """Which triangle of a mesh is nearest to query points (Open3D ray-casting scene). The
    scene computes in float32, so coordinates are taken relative to the mesh's centre; a
    slightly wrong choice only loosens a bound, never breaks it."""

    def __init__(self, mesh: SurfaceMesh):
        v = np.asarray(mesh.vertices, float)
        self.origin = v.mean(axis=0)
        self.corners = v[np.asarray(mesh.triangles, np.int64)]  # (M, 3, 3)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor((v - self.origin).astype(np.float32)),
            o3d.core.Tensor(np.asarray(mesh.triangles).astype(np.uint32)),
        )

    def ids(self, points: np.ndarray) -> np.ndarray:
        query = o3d.core.Tensor((points - self.origin).astype(np.float32))
        return self.scene.compute_closest_points(query)["primitive_ids"].numpy().astype(np.int64)


def _corner_bound(cells: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Largest distance of each cell's corners (N, 3, 3) to its triangle (N, 3, 3): the
    distance to a triangle is convex, so this bounds it over the whole cell."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    worst = point_triangle_distances(cells[:, 0], a, b, c)
    for j in (1, 2):
        worst = np.maximum(worst, point_triangle_distances(cells[:, j], a, b, c))
    return worst


def _cell_bounds(
    cells: np.ndarray, target: _NearestTriangles, found_m: float, tolerance_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """For cells (N, 3, 3): an upper bound of the distance to the target over each cell, and
    the distance at its centroid. The bound is the smaller of the corner bound for the
    triangle nearest the centroid and the centroid's distance plus the cell's radius (the
    distance is 1-Lipschitz). Cells still more than `tolerance_m` above the largest distance
    found (`found_m` or at a centroid here) also try the triangles nearest their corners (a
    cell across an edge of the target is bounded badly by either side's triangle)."""
    centroid = cells.mean(axis=1)
    tri = target.corners[target.ids(centroid)]
    centre = point_triangle_distances(centroid, tri[:, 0], tri[:, 1], tri[:, 2])
    radius = np.linalg.norm(cells - centroid[:, None], axis=2).max(axis=1)
    bound = np.minimum(_corner_bound(cells, tri), centre + radius)
    threshold_m = max(found_m, float(centre.max())) + tolerance_m
    high = np.nonzero(bound > threshold_m)[0]
    if len(high):
        ids = target.ids(cells[high].reshape(-1, 3)).reshape(-1, 3)
        for j in range(3):
            tri = target.corners[ids[:, j]]
            bound[high] = np.minimum(bound[high], _corner_bound(cells[high], tri))
    return bound, centre


def _split(cells: np.ndarray) -> np.ndarray:
    """Each triangle (N, 3, 3) into four at its edge midpoints."""
    a, b, c = cells[:, 0], cells[:, 1], cells[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    return np.concatenate(
        [
            np.stack([a, ab, ca], axis=1),
            np.stack([ab, b, bc], axis=1),
            np.stack([ca, bc, c], axis=1),
            np.stack([ab, bc, ca], axis=1),
        ]
    )


# Refinement stops here (the bound then stays valid, only looser): 12 halvings take a 10 mm
# triangle to 2.4 um cells, and 4M cells are ~1 GB of corner arrays.
_MAX_LEVELS = 12
_MAX_CELLS = 4_000_000


def one_sided_hausdorff(
    source: SurfaceMesh, target: SurfaceMesh, tolerance_m: float
) -> tuple[float, float]:
    """(upper bound, largest found) of the distance from any point of `source`'s surface to
    `target`'s surface (m)."""
    tris = np.asarray(source.triangles, np.int64)
    if not len(tris):
        return 0.0, 0.0
    cells = np.asarray(source.vertices, float)[tris]
    nearest = _NearestTriangles(target)
    found = 0.0
    settled = 0.0  # the largest bound of the cells no longer split
    for level in range(_MAX_LEVELS + 1):
        bound, centre = _cell_bounds(cells, nearest, found, tolerance_m)
        found = max(found, float(centre.max()))
        split = bound > found + tolerance_m
        if level == _MAX_LEVELS or 4 * split.sum() > _MAX_CELLS:
            split[:] = False
        settled = max(settled, float(bound[~split].max(initial=0.0)))
        if not split.any():
            break
        cells = _split(cells[split])
    return max(settled, found), found


def hausdorff_bound(a: SurfaceMesh, b: SurfaceMesh, tolerance_m: float) -> HausdorffBound:
    """The symmetric Hausdorff distance between the surfaces of `a` and `b` (module doc)."""
    ab, ab_found = one_sided_hausdorff(a, b, tolerance_m)
    ba, ba_found = one_sided_hausdorff(b, a, tolerance_m)
    return HausdorffBound(max(ab, ba), max(ab_found, ba_found), ab, ba)


def export_mesh(mesh: SurfaceMesh, X_WO: np.ndarray, config: MeshExportConfig) -> ExportedMesh:
    """Decimate (in W, metres), measure what that cost, then move into O and the unit."""
    watertight_full = mesh_quality(mesh).watertight
    hausdorff = None
    out = mesh
    if config.decimate_triangles is not None and len(mesh.triangles) > config.decimate_triangles:
        out = decimate(mesh, config.decimate_triangles)
        hausdorff = hausdorff_bound(mesh, out, config.hausdorff_tolerance_m)
    elif config.decimate_triangles is not None:
        hausdorff = HausdorffBound(0.0, 0.0, 0.0, 0.0)
    watertight = watertight_full if out is mesh else mesh_quality(out).watertight
    return ExportedMesh(
        mesh.name,
        to_export_coordinates(out, X_WO, config.units),
        len(mesh.triangles),
        watertight_full,
        watertight,
        hausdorff,
    )


def prepare_exports(
    meshes: dict[str, SurfaceMesh], config: MeshExportConfig, reference: str | None = None
) -> MeshExports:
    """All meshes in one export frame, so that they still overlay one another: the object
    frame is that of `reference` (the primary surface), else of the first mesh."""
    X_WO = np.eye(4)
    used = None
    if config.frame != "world" and meshes:
        used = reference if reference in meshes else next(iter(meshes))
        X_WO = export_frame(meshes[used], config.frame)
    exported = tuple(export_mesh(replace(m, name=n), X_WO, config) for n, m in meshes.items())
    return MeshExports(X_WO, config, used, exported)


def export_record(exports: MeshExports, files: dict[str, list[str]]) -> dict:
    """The side-car (and report) record: unit, frame, X_WO (m), and per mesh its files,
    triangle counts, decimation error (m) and whether it is watertight."""
    c = exports.config
    record: dict = {
        "units": c.units,
        "units_per_m": UNITS_PER_M[c.units],
        "frame": c.frame,
        "X_WO": exports.X_WO.tolist(),
        "to_world": "p_W = X_WO @ [p_file / units_per_m, 1] (metres)",
        "frame_reference_mesh": exports.reference,
        "decimate_triangles": c.decimate_triangles,
        "meshes": {},
    }
    for e in exports.meshes:
        entry: dict = {
            "files": files.get(e.name, []),
            "triangles_full": e.triangles_full,
            "triangles": int(len(e.mesh.triangles)),
            "watertight_full": e.watertight_full,
            "watertight": e.watertight,
        }
        if e.hausdorff is not None:
            entry["hausdorff_bound_m"] = e.hausdorff.bound_m
            entry["hausdorff_found_m"] = e.hausdorff.found_m
        if e.watertight_full and not e.watertight:
            entry["note"] = "decimation broke watertightness: this file is not a closed model"
        record["meshes"][e.name] = entry
    return record

"""The stable resting poses of a rigid object on a flat table: the faces of its convex hull it
can lie on.

An object put down on a table comes to rest on a face of its convex hull (the table touches
the hull, never a dent). Coplanar hull facets are one face (a box's side is two triangles of
the hull). A face holds the object when the centre of mass, dropped perpendicularly onto the
face's plane, falls inside the face: the margin is how far inside (a nudge smaller than that
does not tip it over). Each face's probability is the quasi-static one: the solid angle the
face subtends from the centre of mass over 4 pi, the chance that an object dropped in a random
orientation, gently, lands on it; an unstable face's share rolls on to the stable ones, taken
here in proportion to theirs (the quasi-static estimator of Goldberg et al., "Part pose
statistics: estimators and experiments", IEEE Trans. Robotics and Automation, 1999).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull

from reconstruction.common.transforms import rotation_between

# Facets of one face: normals within this angle and planes within this distance (of the
# object's size). A tessellated round side stays many faces (its facets are some degrees
# apart); a flat face's triangles are one.
COPLANAR_RAD = math.radians(0.5)
COPLANAR_FRACTION = 1e-4


@dataclass(frozen=True, eq=False)
class RestingPose:
    """The object resting on one face of its hull (object frame O, metres).

    down_O: the face's outward unit normal, pointing down into the table when it rests.
    height_m: the centre of mass above the table. area_m2: the face's. margin_m: how far the
    centre of mass, dropped onto the face, lies inside its edges. probability: the share of
    random drops that end on this face (the stable faces' sum to 1). centre_O: the face's
    centroid (where it touches the table)."""

    down_O: np.ndarray
    height_m: float
    area_m2: float
    margin_m: float
    probability: float
    centre_O: np.ndarray

    def R_TO(self) -> np.ndarray:
        """The object's rotation resting on this face, up to a turn about the vertical: in a
        table frame T with z up, `down_O` points to -z."""
        return rotation_between(self.down_O, np.array([0.0, 0.0, -1.0]))


def centre_of_mass(vertices: np.ndarray, triangles: np.ndarray | None = None) -> np.ndarray:
    """The centre of mass of the uniform solid a closed mesh bounds (signed tetrahedra from
    the origin); without triangles, or for a mesh that bounds no solid (open, not wound one
    way: its signed volumes then put the "centre" outside the object), its convex hull's."""
    v = np.asarray(vertices, float)
    hull = ConvexHull(v)
    if triangles is not None and len(triangles):
        com = _solid_centroid(v, np.asarray(triangles))
        if com is not None and np.all(hull.equations[:, :3] @ com + hull.equations[:, 3] < 0):
            return com
    return _solid_centroid(v, _outward(v, hull.simplices, v[hull.vertices].mean(axis=0)))


def _solid_centroid(v: np.ndarray, triangles: np.ndarray) -> np.ndarray | None:
    a, b, c = v[triangles[:, 0]], v[triangles[:, 1]], v[triangles[:, 2]]
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    total = volume.sum()
    if abs(total) < 1e-15:
        return None
    return (volume[:, None] * (a + b + c) / 4.0).sum(axis=0) / total


def _outward(v: np.ndarray, triangles: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The triangles wound so that their normals point away from `inside`."""
    a, b, c = v[triangles[:, 0]], v[triangles[:, 1]], v[triangles[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), a - inside) < 0
    out = triangles.copy()
    out[flip] = out[flip][:, ::-1]
    return out


def resting_poses(
    vertices: np.ndarray,
    centre_of_mass_O: np.ndarray,
    min_margin_m: float = 0.0,
    coplanar_rad: float = COPLANAR_RAD,
) -> tuple[RestingPose, ...]:
    """The faces (N, 3 `vertices` of the object, frame O) it rests on stably, its centre of mass
    `centre_of_mass_O` dropped at least `min_margin_m` inside each, most probable first."""
    v = np.asarray(vertices, float)
    com = np.asarray(centre_of_mass_O, float)
    hull = ConvexHull(v)
    size = float(np.ptp(v, axis=0).max())
    face_of = _coplanar_faces(hull, coplanar_rad, COPLANAR_FRACTION * size)
    faces = int(face_of.max()) + 1
    triangles = v[hull.simplices]
    solid_angle = np.bincount(face_of, _solid_angles(triangles - com), faces)
    normal, centroid, radius = _face_extents(triangles, face_of, faces)
    # Only a face whose circle about its centroid takes in the dropped centre of mass can
    # hold it: a cheap test that leaves the exact one (the face's polygon) to a few faces.
    to_com = com - centroid
    dropped = to_com - np.einsum("ij,ij->i", to_com, normal)[:, None] * normal
    poses = []
    for f in np.flatnonzero(np.linalg.norm(dropped, axis=1) <= radius):
        group = np.flatnonzero(face_of == f)
        polygon = _polygon(v[np.unique(hull.simplices[group])], normal[f])
        margin, area = _margin_and_area(polygon, normal[f], com)
        if margin >= max(min_margin_m, 0.0):
            height = float(normal[f] @ (polygon[0] - com))
            poses.append((normal[f].copy(), height, area, margin, polygon.mean(axis=0), f))
    if not poses:
        return ()
    total = sum(solid_angle[f] for *_, f in poses)
    out = []
    for n, height, area, margin, centre, f in poses:
        n.setflags(write=False)
        centre.setflags(write=False)
        out.append(RestingPose(n, height, area, margin, float(solid_angle[f] / total), centre))
    return tuple(sorted(out, key=lambda r: (-r.probability, -r.area_m2)))


def _coplanar_faces(hull: ConvexHull, max_rad: float, max_m: float) -> np.ndarray:
    """The face (label) of each hull facet: neighbouring facets on one plane are one face."""
    n, d = hull.equations[:, :3], hull.equations[:, 3]
    i = np.repeat(np.arange(len(n)), 3)
    j = hull.neighbors.ravel()
    same = (np.einsum("ij,ij->i", n[i], n[j]) >= math.cos(max_rad)) & (np.abs(d[i] - d[j]) <= max_m)
    graph = coo_matrix((np.ones(same.sum()), (i[same], j[same])), shape=(len(n), len(n)))
    return connected_components(graph, directed=False)[1]


def _face_extents(
    triangles: np.ndarray, face_of: np.ndarray, faces: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per face: its unit normal (its facets' area-weighted), its centroid and the radius
    about the centroid that takes in its corners."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    cross = np.cross(b - a, c - a)
    # Qhull does not wind its facets one way: the area vectors point away from the hull's
    # centre.
    inside = triangles.reshape(-1, 3).mean(axis=0)
    cross *= np.sign(np.einsum("ij,ij->i", cross, a - inside))[:, None]
    area = np.linalg.norm(cross, axis=1) / 2
    normal = np.stack([np.bincount(face_of, cross[:, k], faces) for k in range(3)], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    weight = np.bincount(face_of, area, faces)
    centre = triangles.mean(axis=1)
    centroid = (
        np.stack([np.bincount(face_of, area * centre[:, k], faces) for k in range(3)], axis=1)
        / np.maximum(weight, 1e-300)[:, None]
    )
    reach = np.linalg.norm(triangles - centroid[face_of][:, None, :], axis=2).max(axis=1)
    radius = np.zeros(faces)
    np.maximum.at(radius, face_of, reach)
    return normal, centroid, radius


def _plane_basis(n: np.ndarray) -> np.ndarray:
    """Two unit vectors (2, 3) spanning the plane normal to `n`."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(n, e1)])


def _polygon(corners: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The face's corners in order around it (K, 3), on its plane."""
    E = _plane_basis(n)
    uv = (corners - corners.mean(axis=0)) @ E.T
    order = np.argsort(np.arctan2(uv[:, 1], uv[:, 0]))
    if len(corners) > 3:
        hull2 = ConvexHull(uv)
        order = hull2.vertices  # counter-clockwise in (e1, e2)
    return corners[order]


def _margin_and_area(polygon: np.ndarray, n: np.ndarray, com: np.ndarray) -> tuple[float, float]:
    """How far inside the face the centre of mass drops (negative: outside) and its area."""
    E = _plane_basis(n)
    uv = polygon @ E.T
    p = com @ E.T
    edges = np.roll(uv, -1, axis=0) - uv
    area = 0.5 * float(np.sum(uv[:, 0] * np.roll(uv[:, 1], -1) - uv[:, 1] * np.roll(uv[:, 0], -1)))
    sign = 1.0 if area >= 0 else -1.0
    # Inside a counter-clockwise polygon every edge has the point on its left.
    left = (edges[:, 0] * (p[1] - uv[:, 1]) - edges[:, 1] * (p[0] - uv[:, 0])) * sign
    margin = float(np.min(left / np.linalg.norm(edges, axis=1)))
    return margin, abs(area)


def _solid_angles(r: np.ndarray) -> np.ndarray:
    """The solid angle (sr) each triangle (F, 3, 3, corners relative to the apex) subtends
    from the apex (Van Oosterom & Strackee, IEEE Trans. Biomed. Eng. 1983)."""
    a, b, c = r[:, 0], r[:, 1], r[:, 2]
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    numerator = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
    denominator = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la
    return 2.0 * np.arctan2(numerator, denominator)

"""Objects to scan: built-in shapes generated here, or any OBJ/PLY/STL mesh, with a stereo texture.

Every object is a triangle mesh in its own frame O (origin at the centre of its bounding box, +z
up), scaled so that its largest extent equals the requested size. For rendering it gets a
procedural multi-scale noise texture: real stereo scanners project a random pattern onto the
object; the painted texture stands in for that projector so that SGBM has something to match.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from reconstruction.common.errors import ScannerError


@dataclass(frozen=True, eq=False)
class ObjectMesh:
    """Triangle mesh in the object frame O: vertices (N, 3) in metres, triangles (M, 3)."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    smooth: bool = True

    def __post_init__(self) -> None:
        for a in (self.vertices, self.triangles):
            a.setflags(write=False)

    @property
    def extent_m(self) -> np.ndarray:
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)


def _normalised(
    name: str, vertices: np.ndarray, triangles: np.ndarray, size_m: float, smooth: bool = True
) -> ObjectMesh:
    """Centre on the bounding box and scale the largest extent to size_m."""
    if not (math.isfinite(size_m) and size_m > 0):
        raise ScannerError(f"object size must be a positive number of metres, got {size_m}")
    v = np.asarray(vertices, dtype=float)
    t = np.asarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or t.ndim != 2 or len(t) < 4:
        raise ScannerError(f"object '{name}': the mesh is empty (no triangles)")
    if not np.all(np.isfinite(v)):
        raise ScannerError(f"object '{name}': the mesh has NaN or infinite vertex coordinates")
    if t.min() < 0 or t.max() >= len(v):
        raise ScannerError(f"object '{name}': triangle indices out of range")
    lo, hi = v.min(axis=0), v.max(axis=0)
    extent = float((hi - lo).max())
    if extent <= 0:
        raise ScannerError(f"object '{name}': the mesh is degenerate (zero extent)")
    v = (v - (lo + hi) / 2) * (size_m / extent)
    return ObjectMesh(name, v, t, smooth)


def _vase(size_m: float) -> ObjectMesh:
    """A closed surface of revolution with a waisted, fluted profile."""
    n_theta, n_z = 128, 96
    s = np.linspace(0.0, 1.0, n_z)
    radius = 0.28 + 0.12 * np.sin(2 * np.pi * (0.85 * s + 0.05)) + 0.08 * s
    theta = np.linspace(0, 2 * np.pi, n_theta, endpoint=False)
    flutes = 1.0 + 0.04 * np.cos(8 * theta)
    r = radius[:, None] * flutes[None, :]
    z = np.repeat(s[:, None], n_theta, axis=1)
    ring = np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=-1).reshape(-1, 3)
    vertices = np.vstack([ring, [[0, 0, 0], [0, 0, 1]]])
    bottom, top = len(ring), len(ring) + 1
    tris = []
    for i in range(n_z - 1):
        for j in range(n_theta):
            a, b = i * n_theta + j, i * n_theta + (j + 1) % n_theta
            c, d = a + n_theta, b + n_theta
            tris += [(a, b, d), (a, d, c)]
    last = (n_z - 1) * n_theta
    for j in range(n_theta):
        jn = (j + 1) % n_theta
        tris += [(bottom, jn, j), (top, last + j, last + jn)]
    return _normalised("vase", vertices, np.array(tris), size_m)


def _bracket(size_m: float) -> ObjectMesh:
    """An L-bracket with a gusset and four through holes: sharp edges and concavities."""
    from manifold3d import Manifold

    base = Manifold.cube((0.20, 0.12, 0.02))
    upright = Manifold.cube((0.02, 0.12, 0.16))
    gusset = Manifold.cube((0.08, 0.015, 0.08)).rotate((0, -45, 0)).translate(
        (0.02, 0.0525, 0.02)
    ) ^ Manifold.cube((0.10, 0.015, 0.10)).translate((0.02, 0.0525, 0.02))
    solid = base + upright + gusset
    for x, y in ((0.09, 0.03), (0.15, 0.09)):
        solid -= Manifold.cylinder(0.06, 0.011, -1, 48).translate((x, y, -0.02))
    for y, z in ((0.03, 0.08), (0.09, 0.12)):
        solid -= Manifold.cylinder(0.06, 0.013, -1, 48).rotate((0, 90, 0)).translate((-0.02, y, z))
    mesh = solid.to_mesh()
    return _normalised("bracket", mesh.vert_properties[:, :3], mesh.tri_verts, size_m, smooth=False)


def _pebble(size_m: float) -> ObjectMesh:
    """A smooth organic blob: a sphere displaced by low-frequency lobes."""
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=80)
    d = np.asarray(sphere.vertices)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    r = 1.0 + 0.18 * np.sin(3 * x + 0.5) * np.cos(2 * y) + 0.12 * np.sin(4 * z + 1.0) + 0.1 * x * y
    v = d * r[:, None] * np.array([1.0, 0.8, 0.65])
    return _normalised("pebble", v, np.asarray(sphere.triangles), size_m)


BUILTIN_OBJECTS: dict[str, Callable[[float], ObjectMesh]] = {
    "vase": _vase,
    "bracket": _bracket,
    "pebble": _pebble,
}
MESH_SUFFIXES = (".obj", ".ply", ".stl")


def load_mesh_file(path: Path, size_m: float) -> ObjectMesh:
    from reconstruction.common.mesh_files import read_triangle_mesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ScannerError(
            f"{path}: unsupported mesh type; expected one of {', '.join(MESH_SUFFIXES)}"
        )
    if not path.is_file():
        raise ScannerError(f"{path}: no such mesh file")
    mesh = read_triangle_mesh(path)
    if len(mesh.triangles) == 0:
        raise ScannerError(f"{path}: unreadable or empty mesh (no triangles)")
    return _normalised(path.stem, np.asarray(mesh.vertices), np.asarray(mesh.triangles), size_m)


MESH_PATH_ENV = "SCANNER_MESH_PATH"


def find_named_mesh(name: str) -> Path | None:
    """The mesh file called `name` in the folders of $SCANNER_MESH_PATH (os.pathsep-separated):
    the file whose stem is `name`, else the one whose stem has `name` as a word (so `bunny`
    finds `stanford-bunny.obj`); None when there is none; an error when several match."""
    folders = [Path(f) for f in os.environ.get(MESH_PATH_ENV, "").split(os.pathsep) if f]
    files = [
        p
        for folder in folders
        if folder.is_dir()
        for p in sorted(folder.iterdir())
        if p.suffix.lower() in MESH_SUFFIXES and p.is_file()
    ]
    key = name.lower()
    exact = [p for p in files if p.stem.lower() == key]
    matches = exact or [p for p in files if key in re.split(r"[-_. ]+", p.stem.lower())]
    if len(matches) > 1:
        raise ScannerError(
            f"object '{name}' is ambiguous in ${MESH_PATH_ENV}: "
            f"{', '.join(str(p) for p in matches)}; give the file path"
        )
    return matches[0] if matches else None


def resolve_object(spec: str, size_m: float) -> ObjectMesh:
    """A built-in name, a mesh file path, or the name of a mesh in $SCANNER_MESH_PATH -> the
    object mesh at the requested size."""
    if spec in BUILTIN_OBJECTS:
        return BUILTIN_OBJECTS[spec](size_m)
    if Path(spec).suffix.lower() in MESH_SUFFIXES:
        return load_mesh_file(Path(spec), size_m)
    named = find_named_mesh(spec)
    if named is not None:
        return load_mesh_file(named, size_m)
    raise ScannerError(
        f"unknown object '{spec}': use a built-in name ({', '.join(BUILTIN_OBJECTS)}), "
        f"a mesh file path ({', '.join(MESH_SUFFIXES)}), or the name of a mesh file in a "
        f"folder listed in ${MESH_PATH_ENV}"
    )


def noise_texture(size_px: int, texel_m: float, seed: int) -> np.ndarray:
    """Multi-scale value noise (features 0.6-10 mm), contrast-stretched, as an RGB uint8 image."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((size_px, size_px), np.float32)
    for feature_m, weight in (
        (0.0006, 0.6),
        (0.0012, 1.0),
        (0.0025, 0.8),
        (0.005, 0.6),
        (0.010, 0.4),
    ):
        cells = max(2, int(round(size_px * texel_m / feature_m)))
        grid = rng.standard_normal((cells, cells)).astype(np.float32)
        acc += weight * cv2.resize(grid, (size_px, size_px), interpolation=cv2.INTER_CUBIC)
    acc = (acc - acc.mean()) / (acc.std() + 1e-9)
    gray = np.clip(128 + 55 * acc, 0, 255)
    tint = np.array([1.0, 0.92, 0.8], np.float32)
    return np.clip(gray[..., None] * tint, 0, 255).astype(np.uint8)


def _corner_normals(mesh: ObjectMesh) -> np.ndarray:
    """Per-corner normals (M, 3, 3): vertex normals for smooth objects, face normals otherwise."""
    v, t = mesh.vertices, mesh.triangles
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    if mesh.smooth:
        vn = np.zeros_like(v)
        for k in range(3):
            np.add.at(vn, t[:, k], fn)
        n = vn[t]
    else:
        n = np.repeat(fn[:, None, :], 3, axis=1)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def _planar_uvs(mesh: ObjectMesh) -> np.ndarray:
    """Per-corner UVs (M, 3, 2): each face projected on the plane of its dominant normal axis."""
    v, t = mesh.vertices, mesh.triangles
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    axis = np.argmax(np.abs(fn), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    lo, extent = v.min(axis=0), float(mesh.extent_m.max())
    corners = (v[t] - lo) / extent
    uv = np.take_along_axis(corners, np.repeat(keep[:, None, :], 3, axis=1), axis=2)
    return np.clip(uv, 0.0, 1.0)


TEXTURE_SIZE_PX = 2048


def mesh_fingerprint(mesh: ObjectMesh, texture_seed: int) -> str:
    h = hashlib.sha256()
    h.update(mesh.vertices.tobytes())
    h.update(mesh.triangles.tobytes())
    h.update(f"{mesh.smooth}:{texture_seed}:{TEXTURE_SIZE_PX}:v1".encode())
    return h.hexdigest()[:16]


def write_textured_obj(mesh: ObjectMesh, directory: Path, texture_seed: int = 0) -> Path:
    """Write object.obj + object.mtl + texture.png (v, vt, vn, f v/vt/vn) for Drake's renderer."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    obj_path = directory / "object.obj"
    if not collision_hull_path(obj_path).is_file():
        write_hull_obj(mesh.vertices, collision_hull_path(obj_path))
    if obj_path.is_file():
        return obj_path
    texel_m = float(mesh.extent_m.max()) / TEXTURE_SIZE_PX
    texture = noise_texture(TEXTURE_SIZE_PX, texel_m, texture_seed)
    cv2.imwrite(str(directory / "texture.png"), cv2.cvtColor(texture, cv2.COLOR_RGB2BGR))
    (directory / "object.mtl").write_text(
        "newmtl textured\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd texture.png\n"
    )
    m = len(mesh.triangles)
    uv = _planar_uvs(mesh).reshape(-1, 2)
    normals = _corner_normals(mesh).reshape(-1, 3)
    corner = np.arange(3 * m).reshape(m, 3) + 1
    faces = np.stack([mesh.triangles + 1, corner, corner], axis=-1).reshape(m, 9)
    lines = ["mtllib object.mtl", "usemtl textured"]
    lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in mesh.vertices]
    lines += [f"vt {u:.6f} {w:.6f}" for u, w in uv]
    lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in normals]
    lines += ["f {}/{}/{} {}/{}/{} {}/{}/{}".format(*f) for f in faces.tolist()]
    tmp = obj_path.with_suffix(".obj.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.rename(obj_path)
    return obj_path


def collision_hull_path(obj_path: Path) -> Path:
    """Where the convex hull of the OBJ at `obj_path` is kept (see `write_hull_obj`)."""
    return Path(obj_path).with_name("collision_hull.obj")


def write_hull_obj(vertices: np.ndarray, path: Path) -> Path:
    """The convex hull of `vertices` as an OBJ. Drake's collision queries use a mesh's convex
    hull anyway; registering the mesh itself makes Drake parse all of it and compute that hull
    again for every simulation built (0.25-0.35 s each for a 12k-vertex object), this file once.
    The vertices are rounded as the textured OBJ writes them, so the hull is that file's."""
    from scipy.spatial import ConvexHull

    points = np.round(np.asarray(vertices, float), 7)
    hull = ConvexHull(points)
    used = np.unique(hull.simplices)
    index = np.full(len(points), -1)
    index[used] = np.arange(len(used))
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in points[used]]
    lines += ["f {} {} {}".format(*(index[f] + 1)) for f in hull.simplices]
    path = Path(path)
    tmp = path.with_suffix(".obj.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.rename(path)
    return path

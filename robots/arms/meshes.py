"""Mesh files Drake cannot read, converted to OBJ once and kept in the cache.

Drake 1.51 reads .obj, .gltf and .vtk meshes (its convex hulls for collision take exactly these);
ROS arm descriptions mostly ship STL collision meshes. STL is read here with numpy (binary and
ASCII), so that loading an arm does not pay Open3D's import.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from reconstruction.common.errors import ScannerError
from robots.cache import cache_dir

DRAKE_MESH_SUFFIXES = (".obj", ".gltf", ".vtk")
CONVERTIBLE_SUFFIXES = (".stl",)

# Binary STL: an 80-byte header, a little-endian uint32 triangle count, then 50 bytes a triangle
# (normal, three vertices as float32, a uint16 attribute).
_STL_HEADER_BYTES = 84
_STL_TRIANGLE = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])


def mesh_cache_dir() -> Path:
    """Where converted meshes are kept."""
    return cache_dir() / "arm_meshes"


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float64, triangles (M, 3) int64) of an STL file, shared corners merged."""
    data = Path(path).read_bytes()
    if len(data) >= _STL_HEADER_BYTES:
        count = int(np.frombuffer(data, "<u4", count=1, offset=80)[0])
        if len(data) == _STL_HEADER_BYTES + count * _STL_TRIANGLE.itemsize:
            triangles = np.frombuffer(data, _STL_TRIANGLE, count=count, offset=84)
            corners = triangles["vertices"].reshape(-1, 3).astype(np.float64)
            return _merge_corners(corners)
    # An ASCII file's size matches no triangle count; its vertices are the `vertex x y z` lines.
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise ScannerError(f"{path}: not an STL file (neither binary nor ASCII STL)") from None
    rows = [line.split()[1:4] for line in text.splitlines() if line.strip().startswith("vertex")]
    if not rows or len(rows) % 3:
        raise ScannerError(f"{path}: not an STL file (no triangles of 3 vertices found)")
    return _merge_corners(np.array(rows, dtype=np.float64))


def _merge_corners(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    vertices, index = np.unique(corners, axis=0, return_inverse=True)
    return vertices, index.reshape(-1, 3).astype(np.int64)


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit normals (N, 3) of the vertices, the area-weighted mean of their faces' (a vertex
    on no face, or on faces that cancel, gets +z)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    face = np.cross(b - a, c - a)  # its length is twice the face's area
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(length > 0, normals / np.where(length > 0, length, 1.0), [0.0, 0.0, 1.0])


def obj_text(vertices: np.ndarray, triangles: np.ndarray) -> str:
    """Wavefront OBJ of a triangle mesh with vertex normals (OBJ indices start at 1). Drake's
    renderer refuses an OBJ without normals."""
    v = "\n".join(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices)
    n = "\n".join(f"vn {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertex_normals(vertices, triangles))
    f = "\n".join(f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in triangles + 1)
    return f"{v}\n{n}\n{f}\n"


def drake_readable(path: Path, cache: Path | None = None) -> Path:
    """`path` itself if Drake reads it, else its OBJ conversion in the cache (content-addressed,
    written once, so an edited source mesh gets a new file)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in DRAKE_MESH_SUFFIXES:
        return path
    if suffix not in CONVERTIBLE_SUFFIXES:
        readable = ", ".join(DRAKE_MESH_SUFFIXES + CONVERTIBLE_SUFFIXES)
        raise ScannerError(f"{path}: mesh format {suffix} is not supported (expected {readable})")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    # "-n": with normals; conversions cached before they had them keep their old name.
    target = (cache or mesh_cache_dir()) / f"{path.stem}-{digest}-n.obj"
    if not target.exists():
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_suffix(f".{os.getpid()}.tmp")
        partial.write_text(obj_text(*read_stl(path)))
        # Atomic: a concurrent loader sees either no file or the whole file.
        partial.replace(target)
    return target

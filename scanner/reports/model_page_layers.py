"""What model.html shows, as records and pure geometry: the display mesh (decimated, one value
per vertex), each view's camera frustum, box outlines and the camera that frames the model.
Nothing here needs Meshcat; `model_page` draws these records."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from reconstruction.common.transforms import transform_points
from reconstruction.stereo.camera_model import PinholeCamera

if TYPE_CHECKING:  # building a scene needs no Drake
    from robots.models.workcell import WorkcellConfig

# Meshcat's default perspective camera (three.js PerspectiveCamera, vertical field of view).
MESHCAT_FOV_Y_RAD = math.radians(75.0)
# The page's largest mesh: enough triangles for a 0.2 m object at about 1 mm edges, and a page
# of a few MB (a vertex and a colour in float32, a triangle in uint32, base64 in the page).
DISPLAY_TRIANGLES = 120_000
DISPLAY_POINTS = 20_000
FRUSTUM_DEPTH_M = 0.05  # small: 48 views around a 0.2 m object must not hide it


@dataclass(frozen=True, eq=False)
class DisplayMesh:
    """A mesh as the page shows it: vertices (V, 3) m in W, triangles (M, 3), and per vertex
    the value its colour encodes (m, e.g. the signed deviation from the truth)."""

    vertices_W: np.ndarray
    triangles: np.ndarray
    values_m: np.ndarray


@dataclass(frozen=True, eq=False)
class ViewFrustum:
    """One view's camera pose X_WC (4x4, optical frame: z forward, x right, y down) and the
    hanging it belongs to (0-based)."""

    X_WC: np.ndarray
    hanging: int = 0


@dataclass(frozen=True, eq=False)
class RobotPose:
    """The arm at one configuration (q_rad, one per joint), with the tool's camera frames at
    X_FC and the pair's X_CR (they only place frames; the tool's shape is the model's);
    `robot`: the arm, as a configuration's `robot` names it (drawn from its own model)."""

    q_rad: np.ndarray
    X_FC: np.ndarray
    X_CR: np.ndarray
    robot: str = "rx60"


@dataclass(frozen=True, eq=False)
class ModelScene:
    """Everything model.html shows, in the first hanging's world frame W (metres).

    mesh: the headline mesh coloured by `values_m` on the fixed scale +-scale_m (blue inside,
    red outside; `signed` False: distances, 0..scale_m, the map's white-to-red half);
    colour_meaning: what the colours are, for the page's caption; unseen_W (K, 3): points of
    the true surface no view saw;
    frustums + camera: the views; fixture_segments: (start, end) pairs of the rods' axes;
    cell: the cell (its boxes are outlined; the arm is built in it); robot: the arm at one
    pose; reference: a reference mesh (an inspection) drawn as a wireframe."""

    mesh: DisplayMesh
    scale_m: float
    colour_meaning: str
    signed: bool = True
    unseen_W: np.ndarray | None = None
    frustums: tuple[ViewFrustum, ...] = ()
    camera: PinholeCamera | None = None
    fixture_segments: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    cell: WorkcellConfig | None = None
    robot: RobotPose | None = None
    reference: DisplayMesh | None = None


def decimated(
    vertices: np.ndarray, triangles: np.ndarray, max_triangles: int = DISPLAY_TRIANGLES
) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with at most `max_triangles` (quadric decimation keeps the shape where it
    matters); a smaller mesh is returned as it is. Only what is displayed is decimated."""
    vertices = np.asarray(vertices, float)
    triangles = np.asarray(triangles, np.int64)
    if len(triangles) <= max_triangles:
        return vertices, triangles
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
    )
    small = mesh.simplify_quadric_decimation(target_number_of_triangles=max_triangles)
    small.remove_unreferenced_vertices()
    return np.asarray(small.vertices).copy(), np.asarray(small.triangles).copy()


def thinned(points: np.ndarray, max_points: int = DISPLAY_POINTS, seed: int = 0) -> np.ndarray:
    """At most `max_points` of the points, drawn at random (the same on every run)."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) <= max_points:
        return points
    keep = np.random.default_rng(seed).choice(len(points), max_points, replace=False)
    return points[np.sort(keep)]


def frustum_segments(
    X_WC: np.ndarray, camera: PinholeCamera, depth_m: float = FRUSTUM_DEPTH_M
) -> tuple[np.ndarray, np.ndarray]:
    """The camera's viewing pyramid cut at `depth_m`: 8 segments (apex to the four image
    corners, and the image rectangle), as start and end points (8, 3) in W."""
    K = camera.K
    u = np.array([0.0, camera.width, camera.width, 0.0])
    v = np.array([0.0, 0.0, camera.height, camera.height])
    p_C = np.column_stack(
        [(u - K[0, 2]) / K[0, 0] * depth_m, (v - K[1, 2]) / K[1, 1] * depth_m, np.full(4, depth_m)]
    )
    corners = transform_points(np.asarray(X_WC, float), p_C)
    apex = np.repeat(np.asarray(X_WC, float)[None, :3, 3], 4, axis=0)
    start = np.vstack([apex, corners])
    end = np.vstack([corners, np.roll(corners, -1, axis=0)])
    return start, end


def box_segments(centre: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 12 edges of an axis-aligned box as start and end points (12, 3)."""
    half = 0.5 * np.asarray(size, float)
    corner = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    p = np.asarray(centre, float) + corner * half
    # Corners differing in exactly one sign are joined by an edge.
    pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
    return p[[i for i, _ in pairs]], p[[j for _, j in pairs]]


def framing(
    points_W: np.ndarray, aspect: float = 4 / 3, fov_y_rad: float = MESHCAT_FOV_Y_RAD
) -> tuple[np.ndarray, np.ndarray]:
    """Where the page's camera starts (p_WCamera) and what it looks at (p_WTarget): the
    bounding sphere of the points fills about 70 % of the narrower field of view, seen from
    the front (+x, the side facing away from the robot), a little from the side and above."""
    points_W = np.asarray(points_W, float)
    lo, hi = points_W.min(axis=0), points_W.max(axis=0)
    target = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    half_fov = 0.5 * min(fov_y_rad, 2 * math.atan(aspect * math.tan(0.5 * fov_y_rad)))
    distance = radius / math.sin(0.7 * half_fov)
    direction = np.array([1.0, 0.55, 0.35])
    return target + distance * direction / np.linalg.norm(direction), target

"""Accuracy of a reconstruction against the true surface, and of a hand-eye estimate.

Distances are computed in metres; the report keys are in millimetres and degrees (the printing
edge, named by unit). Conventions, for result R and truth T:
- result -> truth: exact point-to-triangle distance from every result point to the true mesh;
- truth -> result: from points sampled uniformly by area on the true mesh to the result (exact
  point-to-triangle when the result is a mesh, nearest point when it is a cloud);
- chamfer_mm: the mean of the two directions' mean distances;
- fscore at tau: harmonic mean of precision (result points within tau of the truth) and recall
  (truth samples within tau of the result); completeness_2mm is that recall at 2 mm;
- accuracy_p90_mm: 90th percentile of result -> truth.
The "observed" variants restrict the truth samples to those at least one view saw: for a stereo
view, BOTH of its cameras see the sample (not occluded, facing each within `max_incidence_rad`),
as stereo measures nothing that only one camera sees. The RX60 reaches only a band of viewing
directions, so whole-object completeness mixes sensing quality with coverage.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from reconstruction.common.kdtree import query_workers
from reconstruction.common.transforms import pose_difference
from reconstruction.evaluation.support import SupportPlane


@dataclass(frozen=True, eq=False)
class TriangleSurface:
    """A triangle mesh (V, 3) metres, (M, 3) indices, as the metrics see it."""

    vertices: np.ndarray
    triangles: np.ndarray


@dataclass(frozen=True, eq=False)
class SurfaceSamples:
    points: np.ndarray
    normals: np.ndarray


def sample_surface(surface: TriangleSurface, n: int, seed: int = 0) -> SurfaceSamples:
    """n points uniformly by area (triangle chosen by area, then uniform barycentric)."""
    rng = np.random.default_rng(seed)
    v = np.asarray(surface.vertices, float)
    t = np.asarray(surface.triangles, np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    k = rng.choice(len(t), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    points = (1 - s)[:, None] * a[k] + (s * (1 - r2))[:, None] * b[k] + (s * r2)[:, None] * c[k]
    normals = cross[k] / np.maximum(np.linalg.norm(cross[k], axis=1, keepdims=True), 1e-300)
    return SurfaceSamples(points, normals)


def _scene(surface: TriangleSurface, origin: np.ndarray) -> o3d.t.geometry.RaycastingScene:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor((np.asarray(surface.vertices) - origin).astype(np.float32)),
        o3d.core.Tensor(np.asarray(surface.triangles).astype(np.uint32)),
    )
    return scene


def distances_to_mesh(points: np.ndarray, surface: TriangleSurface) -> np.ndarray:
    """Exact point-to-triangle distances (m). Open3D computes in float32, so coordinates are
    taken relative to the mesh's centre first: 1e-7 relative of 0.2 m, not of 1 m."""
    origin = np.asarray(surface.vertices).mean(axis=0)
    query = (np.asarray(points) - origin).astype(np.float32)
    return _scene(surface, origin).compute_distance(o3d.core.Tensor(query)).numpy().astype(float)


def distances_to_points(points: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Nearest-neighbour distances (m) from each point to the target cloud."""
    points = np.asarray(points)
    return cKDTree(np.asarray(target)).query(points, workers=query_workers(len(points)))[0]


def _sees(scene, p, normals, centre, todo, max_incidence_rad, offset_m) -> np.ndarray:
    """Which of the points `todo` (mask) the camera at `centre` sees (all in the scene's
    shifted coordinates): facing it and nothing in between."""
    seen = np.zeros(len(p), bool)
    # Only the points still to do: after the first views most samples are settled.
    idx = np.flatnonzero(todo)
    to_cam = centre - p[idx]
    dist = np.linalg.norm(to_cam, axis=1)
    d = to_cam / dist[:, None]
    facing = np.einsum("ij,ij->i", d, normals[idx]) > math.cos(max_incidence_rad)
    if facing.any():
        idx, d, dist = idx[facing], d[facing], dist[facing]
        rays = np.hstack([p[idx] + offset_m * d, d]).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        seen[idx[hit >= dist - offset_m]] = True
    return seen


def _seen_by_every_eye(scene, p, normals, eyes, todo, max_incidence_rad, offset_m) -> np.ndarray:
    """Which of the points `todo` every eye of one view sees (`eyes`: (k, 3) or (3,) centres in
    the scene's shifted coordinates)."""
    for eye in np.atleast_2d(eyes):
        todo = _sees(scene, p, normals, eye, todo, max_incidence_rad, offset_m)
    return todo


def _shifted(
    samples: SurfaceSamples, surface: TriangleSurface, camera_centres_W: Sequence[np.ndarray]
) -> tuple[o3d.t.geometry.RaycastingScene, np.ndarray, list[np.ndarray]]:
    """The surface's ray-casting scene, the sample points and each view's eye centres, all
    relative to the surface's mean vertex (Open3D casts in float32; see distances_to_mesh)."""
    origin = np.asarray(surface.vertices).mean(axis=0)
    views = [np.asarray(centre) - origin for centre in camera_centres_W]
    return _scene(surface, origin), samples.points - origin, views


def visible_mask(
    samples: SurfaceSamples,
    surface: TriangleSurface,
    camera_centres_W: Sequence[np.ndarray],
    max_incidence_rad: float = math.radians(80.0),
    offset_m: float = 1e-4,
    supports: Sequence[SupportPlane | None] | None = None,
) -> np.ndarray:
    """True for samples that at least one view sees. A view is a camera centre (3,) or the eye
    centres (k, 3) of a stereo rig (see `StereoCamera.eye_centres_W`), all of which must see
    the sample. An eye sees it when the sample faces it (angle between its outward normal and
    the direction to the eye below `max_incidence_rad`) and the segment to it hits no triangle.
    Rays start `offset_m` off the surface so that they do not hit their own triangle.
    `supports`: per view, the top of what holds the object in that view's pass (None: nothing),
    which hides what lies on or below it (reconstruction/evaluation/support.py)."""
    scene, p, views = _shifted(samples, surface, camera_centres_W)
    seen = np.zeros(len(p), bool)
    for k, eyes in enumerate(views):
        todo = ~seen
        support = None if supports is None else supports[k]
        if support is not None:
            todo &= support.exposed(samples.points)
        seen |= _seen_by_every_eye(
            scene, p, samples.normals, eyes, todo, max_incidence_rad, offset_m
        )
    return seen


def visibility(
    samples: SurfaceSamples,
    surface: TriangleSurface,
    camera_centres_W: Sequence[np.ndarray],
    max_incidence_rad: float = math.radians(80.0),
    offset_m: float = 1e-4,
):
    """For each view (camera centre or stereo eye centres) in turn, which samples it sees (the
    rule of `visible_mask`); the surface's ray-casting scene is built once."""
    scene, p, views = _shifted(samples, surface, camera_centres_W)
    everything = np.ones(len(p), bool)
    for eyes in views:
        yield _seen_by_every_eye(
            scene, p, samples.normals, eyes, everything, max_incidence_rad, offset_m
        )


def surface_metrics(
    result_to_truth_m: np.ndarray,
    truth_to_result_m: np.ndarray,
    observed: np.ndarray | None = None,
    observable: np.ndarray | None = None,
) -> dict[str, float]:
    """The report's keys from the two distance sets (m in, mm out). `observed`: mask over the
    truth samples; adds the *_observed_* keys and `observed_fraction`. `observable`: mask of
    the samples a camera could see from anywhere around (evaluation/observable.py); adds
    `observable_fraction` and `completeness_observable_2mm`."""
    d_rt = np.asarray(result_to_truth_m, float)
    d_tr = np.asarray(truth_to_result_m, float)
    out = {
        "chamfer_mm": 1e3 * 0.5 * (d_rt.mean() + d_tr.mean()),
        "fscore_1mm": fscore(d_rt, d_tr, 0.001),
        "fscore_2mm": fscore(d_rt, d_tr, 0.002),
        "completeness_2mm": float(np.mean(d_tr < 0.002)),
        "accuracy_p90_mm": 1e3 * float(np.percentile(d_rt, 90)),
        "accuracy_mean_mm": 1e3 * float(d_rt.mean()),
    }
    if observed is not None:
        obs = d_tr[np.asarray(observed, bool)]
        out["observed_fraction"] = float(np.mean(observed))
        if len(obs):
            out["chamfer_observed_mm"] = 1e3 * 0.5 * (d_rt.mean() + obs.mean())
            out["fscore_observed_1mm"] = fscore(d_rt, obs, 0.001)
            out["completeness_observed_2mm"] = float(np.mean(obs < 0.002))
            out["completeness_observed_1mm"] = float(np.mean(obs < 0.001))
    if observable is not None:
        can = np.asarray(observable, bool)
        out["observable_fraction"] = float(np.mean(can))
        if can.any():
            out["completeness_observable_2mm"] = float(np.mean(d_tr[can] < 0.002))
    return {k: float(v) for k, v in out.items()}


def fscore(result_to_truth_m: np.ndarray, truth_to_result_m: np.ndarray, tau_m: float) -> float:
    precision = float(np.mean(np.asarray(result_to_truth_m) < tau_m))
    recall = float(np.mean(np.asarray(truth_to_result_m) < tau_m))
    return 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)


def evaluate_surface(
    result_points: np.ndarray,
    truth: TriangleSurface,
    result_mesh: TriangleSurface | None = None,
    camera_centres_W: Sequence[np.ndarray] | None = None,
    n_samples: int = 200_000,
    seed: int = 0,
    max_incidence_rad: float = math.radians(80.0),
    truth_samples: tuple[SurfaceSamples, np.ndarray | None] | None = None,
    observable: np.ndarray | None = None,
) -> dict[str, float]:
    """Metrics of a result (its points, and its mesh when it is one: then the result -> truth
    direction uses the mesh's own area-uniform samples) against the true mesh.
    `truth_samples`: (samples, observed mask) from `truth_sampling` with the same arguments,
    to evaluate several results against one truth without sampling and ray casting again;
    `observable`: the mask of those samples some camera could see at all (`surface_metrics`)."""
    samples, observed = truth_samples or truth_sampling(
        truth, camera_centres_W, n_samples, seed, max_incidence_rad
    )
    if result_mesh is not None:
        result_points = sample_surface(result_mesh, n_samples, seed + 1).points
        d_tr = distances_to_mesh(samples.points, result_mesh)
    else:
        d_tr = distances_to_points(samples.points, result_points)
    d_rt = distances_to_mesh(result_points, truth)
    return surface_metrics(d_rt, d_tr, observed, observable)


def truth_sampling(
    truth: TriangleSurface,
    camera_centres_W: Sequence[np.ndarray] | None = None,
    n_samples: int = 200_000,
    seed: int = 0,
    max_incidence_rad: float = math.radians(80.0),
    supports: Sequence[SupportPlane | None] | None = None,
) -> tuple[SurfaceSamples, np.ndarray | None]:
    """Area-uniform samples of the true surface and which of them the cameras saw (None
    without camera centres; `supports`: per view, as `visible_mask` takes them)."""
    samples = sample_surface(truth, n_samples, seed)
    observed = (
        None
        if camera_centres_W is None
        else visible_mask(samples, truth, camera_centres_W, max_incidence_rad, supports=supports)
    )
    return samples, observed


# The headline keys of a report against the truth (a surface's metrics, then the hand-eye's).
SURFACE_METRIC_KEYS = (
    "chamfer_mm",
    "fscore_1mm",
    "fscore_2mm",
    "completeness_2mm",
    "accuracy_p90_mm",
    "chamfer_observed_mm",
    "completeness_observed_2mm",
    "fscore_observed_1mm",
    "observed_fraction",
)
HANDEYE_ERROR_KEYS = ("handeye_error_mm", "handeye_error_deg")


def handeye_error(X_FC_estimate: np.ndarray, X_FC_true: np.ndarray) -> dict[str, float]:
    """Translation of the camera origin (mm) and rotation angle (deg) between two X_FC."""
    dt, dr = pose_difference(X_FC_estimate, X_FC_true)
    return {"handeye_error_mm": 1e3 * dt, "handeye_error_deg": math.degrees(dr)}

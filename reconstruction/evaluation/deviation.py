"""Signed deviation of a measured surface from a reference surface (the truth, or a CAD model),
and its statistics, as metrology tools report them.

Sign convention (as in CloudCompare and GOM Inspect): positive where the measured point lies
outside the reference (material in excess), negative inside. The sign comes from the normal of
the reference triangle nearest to the point, so it is defined for open reference meshes too
(the result's unseen top, a CAD shell with holes); the reference must be consistently oriented.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from reconstruction.evaluation.metrics import TriangleSurface


def signed_distances(points: np.ndarray, reference: TriangleSurface) -> np.ndarray:
    """Signed distance (m) from each point to the nearest point of the reference mesh.
    Open3D computes in float32, so coordinates are taken relative to the reference's centre
    first (1e-7 relative of 0.2 m, not of 1 m)."""
    origin = np.asarray(reference.vertices, float).mean(axis=0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor((np.asarray(reference.vertices, float) - origin).astype(np.float32)),
        o3d.core.Tensor(np.asarray(reference.triangles).astype(np.uint32)),
    )
    query = (np.asarray(points, float) - origin).astype(np.float32)
    closest = scene.compute_closest_points(o3d.core.Tensor(query))
    offset = query.astype(float) - closest["points"].numpy().astype(float)
    distance = np.linalg.norm(offset, axis=1)
    side = np.einsum("ij,ij->i", offset, closest["primitive_normals"].numpy().astype(float))
    return np.where(side < 0.0, -distance, distance)


@dataclass(frozen=True)
class DeviationStats:
    """Statistics of signed deviations (m); `within_tolerance` is the share with
    |deviation| <= tolerance_m."""

    points: int
    mean_m: float
    mean_abs_m: float
    rms_m: float
    p90_abs_m: float
    max_abs_m: float
    tolerance_m: float
    within_tolerance: float

    def as_report(self) -> dict:
        """The record for report files: lengths in mm (the printing edge, named by unit)."""
        return {
            "points": self.points,
            "mean_mm": 1e3 * self.mean_m,
            "mean_abs_mm": 1e3 * self.mean_abs_m,
            "rms_mm": 1e3 * self.rms_m,
            "p90_abs_mm": 1e3 * self.p90_abs_m,
            "max_abs_mm": 1e3 * self.max_abs_m,
            "tolerance_mm": 1e3 * self.tolerance_m,
            "within_tolerance": self.within_tolerance,
        }


def deviation_stats(signed_m: np.ndarray, tolerance_m: float) -> DeviationStats:
    d = np.asarray(signed_m, float)
    if d.size == 0:
        raise ValueError("no deviations to summarise")
    a = np.abs(d)
    return DeviationStats(
        points=int(d.size),
        mean_m=float(d.mean()),
        mean_abs_m=float(a.mean()),
        rms_m=float(np.sqrt(np.mean(d * d))),
        p90_abs_m=float(np.percentile(a, 90)),
        max_abs_m=float(a.max()),
        tolerance_m=float(tolerance_m),
        within_tolerance=float(np.mean(a <= tolerance_m)),
    )

"""A reference surface (a CAD model, or the simulator's truth) brought onto a measured model,
for inspection: its unit guessed or given, then the rigid transform found.

The model is usually partial (a hung object shows ~70 % of its surface), so the fit runs from
the model to the reference: every model point should lie on the reference, not the reverse.
Starts: the reference as given (CAD placed in the model's frame, the simulator's truth), then
only if that does not fit, FPFH feature hypotheses (Fast Global Registration, RANSAC runs) and
a rotation grid, each refined by point-to-plane ICP; the best by overlap, then inlier RMS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.evaluation.metrics import TriangleSurface, distances_to_mesh, sample_surface
from reconstruction.hangings.alignment import (
    AlignmentConfig,
    feature_hypotheses,
    icp_coarse_to_fine,
    prepared_features,
    rotation_grid_hypotheses,
)

# Units a reference file may be in (its number -> metres); "auto" picks the one whose size
# is nearest the model's.
UNIT_SCALES = {"m": 1.0, "mm": 1e-3}
# A fit with this share of the model on the reference ends the search (the later starts are
# slower: as given, then features, then the rotation grid).
GOOD_OVERLAP = 0.9


@dataclass(frozen=True)
class ReferenceAlignment:
    """X_MR: the reference's pose in the model's frame (metres, after the unit); overlap: share
    of the model's points within `inlier_distance_m` of it; inlier_rms_m over those points."""

    X_MR: np.ndarray
    unit: str
    start: str  # "as given", "features" or "rotation grid"
    overlap: float
    inlier_rms_m: float
    inlier_distance_m: float


def reference_unit(model_vertices: np.ndarray, reference_vertices: np.ndarray) -> str:
    """The unit (of UNIT_SCALES) under which the reference's size is nearest the model's (a
    partial model is 0.5-1 times the reference's size; m and mm are 1000 times apart)."""
    size_model = float(np.linalg.norm(np.ptp(model_vertices, axis=0)))
    size_ref = float(np.linalg.norm(np.ptp(reference_vertices, axis=0)))
    if size_model <= 0 or size_ref <= 0:
        raise ScannerError("the model or the reference has no extent (a single point?)")
    return min(UNIT_SCALES, key=lambda u: abs(math.log(UNIT_SCALES[u] * size_ref / size_model)))


def scaled(surface: TriangleSurface, unit: str) -> TriangleSurface:
    return TriangleSurface(
        np.asarray(surface.vertices, float) * UNIT_SCALES[unit], surface.triangles
    )


def _fit(model_points: np.ndarray, reference: TriangleSurface, X_RM, distance_m: float):
    d = distances_to_mesh(transform_points(X_RM, model_points), reference)
    inliers = d < distance_m
    rms = float(np.sqrt(np.mean(d[inliers] ** 2))) if inliers.any() else math.inf
    return float(inliers.mean()), rms


def align_reference(
    model_points: np.ndarray,
    reference: TriangleSurface,
    config: AlignmentConfig | None = None,
    unit: str = "m",
    reference_samples: int = 100_000,
) -> ReferenceAlignment:
    """The reference (in `unit`) onto the model points (metres); `config`: the hangings'
    alignment settings (feature voxel, ICP gates, inlier distance) by default."""
    import open3d as o3d

    config = config or AlignmentConfig()
    ref = scaled(reference, unit)
    samples = sample_surface(ref, reference_samples)
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(samples.points))
    target.normals = o3d.utility.Vector3dVector(samples.normals)
    target = target.voxel_down_sample(0.5 * config.voxel_m)
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(model_points, float)))
    source = source.voxel_down_sample(0.5 * config.voxel_m)
    points = np.asarray(source.points)
    gates = (3 * config.voxel_m, config.voxel_m, config.inlier_distance_m)

    def refined(T0: np.ndarray) -> np.ndarray:
        return np.asarray(icp_coarse_to_fine(source, target, T0, gates, 50).transformation)

    best = None
    for start, starts in _starts(points, samples.points, config):
        for T0 in starts:
            X_RM = refined(T0)
            overlap, rms = _fit(points, ref, X_RM, config.inlier_distance_m)
            if best is None or (overlap, -rms) > (best[1], -best[2]):
                best = (X_RM, overlap, rms, start)
        if best[1] >= GOOD_OVERLAP:
            break
    X_RM, overlap, rms, start = best
    return ReferenceAlignment(invert(X_RM), unit, start, overlap, rms, config.inlier_distance_m)


def fit_as_given(
    model_points: np.ndarray,
    reference: TriangleSurface,
    config: AlignmentConfig | None = None,
    unit: str = "m",
) -> ReferenceAlignment:
    """The reference left where it is (placed by a fixture, or the simulator's truth): how
    well it fits, with the same figures as `align_reference`."""
    config = config or AlignmentConfig()
    overlap, rms = _fit(
        np.asarray(model_points, float),
        scaled(reference, unit),
        np.eye(4),
        config.inlier_distance_m,
    )
    return ReferenceAlignment(np.eye(4), unit, "none", overlap, rms, config.inlier_distance_m)


def _starts(model_points: np.ndarray, reference_points: np.ndarray, config: AlignmentConfig):
    """(name, transforms model -> reference) in the order they are tried; the global ones are
    computed only when asked for."""
    yield "as given", [np.eye(4)]
    source, src_f = prepared_features(model_points, config.voxel_m)
    target, tgt_f = prepared_features(reference_points, config.voxel_m)
    yield "features", feature_hypotheses(source, target, src_f, tgt_f, config)
    yield "rotation grid", rotation_grid_hypotheses(source, target, config)

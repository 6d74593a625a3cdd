"""Pairwise registration: which views overlap, and coarse-to-fine point-to-plane ICP between them.

Each view's cloud stays in its own camera frame; a pair (S, T) is registered from the kinematic
guess X_TS = X_CtCs = inv(X_WC_t) @ X_WC_s, and Open3D's `result.transformation` is that X_TS
(target <- source). An edge is kept only if ICP found enough overlap, fits tightly, and did not
move far from the kinematic guess: the robot knows its poses to ~1 cm (the hand-eye error at the
object), so a larger jump means ICP slid into a wrong minimum, which happens on symmetric parts.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from reconstruction.common.checks import check_fields, fraction, integer, positive, require_choice
from reconstruction.common.errors import ScannerError
from reconstruction.common.kdtree import query_workers
from reconstruction.common.transforms import (
    invert,
    pose_difference,
    rotation_angle_rad,
    transform_points,
)
from reconstruction.registration.filtering import FilteredCloud, estimate_normals_towards, o3d_cloud

_reg = o3d.pipelines.registration

# Robust kernels for the point-to-plane ICP, by name; the scale is a fraction of each level's
# correspondence gate. On the synthetic bracket (flat faces, holes) plain point-to-plane slid
# into wrong minima on 15 of 69 pairs (up to 90 deg), Tukey on 5, with the same cost; on the
# pebble both were fine (Tukey slightly tighter).
ROBUST_KERNELS: dict[str, Callable[[float], object] | None] = {
    "none": None,
    "tukey": lambda k: _reg.TukeyLoss(k=k),
    "huber": lambda k: _reg.HuberLoss(k=k),
    "cauchy": lambda k: _reg.CauchyLoss(k=k),
}


@dataclass(frozen=True)
class IcpLevel:
    """One pyramid level: down-sampling voxel, correspondence gate and iteration cap."""

    voxel_size_m: float = positive()
    max_correspondence_m: float = positive()
    max_iterations: int = integer()

    def __post_init__(self) -> None:
        check_fields("icp.levels", self)


def _default_levels() -> tuple[IcpLevel, ...]:
    # The coarse gate (15 mm) exceeds the largest relative error the kinematic guess has for a
    # 3 mm / 1 deg hand-eye error between views up to 70 deg apart (~11 mm); the fine level
    # gates at about twice the stereo noise. It samples at 1.5 mm, not at the clouds' 1 mm: on
    # the 24-view vase ICP took 7.9 s instead of 14.3 s with the same hand-eye result (0.256
    # against 0.261 mm) and fused-cloud accuracy (the final poses come from the joint X_FC fit
    # on the 1 mm clouds, which the pairs only start). At 2 mm (5.2 s) the alignment of two
    # hangings at 640x480 got worse (1.08 mm) on a resumed scan.
    return (
        IcpLevel(0.004, 0.015, 30),
        IcpLevel(0.002, 0.005, 30),
        IcpLevel(0.0015, 0.002, 30),
    )


@dataclass(frozen=True)
class IcpConfig:
    enabled: bool = True
    levels: tuple[IcpLevel, ...] = field(default_factory=_default_levels)
    robust_kernel: str = "tukey"
    robust_kernel_scale: float = positive(0.5)  # kernel width as a fraction of the level's gate
    # Normals at each level from this many voxels around.
    normal_radius_factor: float = positive(3.0)
    normal_max_neighbors: int = integer(30)
    relative_fitness: float = positive(1e-7)
    relative_rmse: float = positive(1e-7)
    # Converged: one more finest-level iteration moves the overlap's centroid less than 10 um
    # and turns it less than 0.006 deg, well below what pairwise ICP resolves (~0.02 deg).
    converged_step_m: float = positive(1e-5)
    converged_step_rad: float = positive(1e-4)
    # Pair selection (`partners_among_earlier`): each view against this many of the views
    # before it, nearest by viewing angle. Measured on the same 24-view captures against the
    # earlier rule (6 nearest in both directions, 94 pairs on the vase), observed Chamfer:
    # 4 earlier (88 pairs) lost up to 0.006 mm (fandisk 0.1763 -> 0.1825), 5 (107 pairs)
    # within 0.002 mm on bunny, spot, fandisk and teapot, 6 (124 pairs) the same.
    max_pair_angle_rad: float = math.radians(60.0)
    max_pairs_per_view: int = integer(5)
    overlap_distance_m: float = positive(0.01)
    min_overlap: float = fraction(0.3)
    # Edge checks (an edge failing one is pruned, with the reason recorded).
    min_fitness: float = fraction(0.3)
    max_inlier_rmse_m: float = positive(0.001)
    max_prior_translation_m: float = positive(0.02)
    max_prior_rotation_rad: float = positive(math.radians(3.0))
    # A pair's registration is reused from another starting guess while that guess places
    # the source's centroid within reuse_within_m of the registration's answer and turns it
    # less than reuse_within_rad from it: ICP's basin, which the first level's 15 mm gate
    # holds for the ~11 mm errors a 3 mm / 1 deg mount gives (see _default_levels).
    reuse_within_m: float = positive(0.01)
    reuse_within_rad: float = positive(math.radians(3.0))

    def __post_init__(self) -> None:
        if not self.levels:
            raise ScannerError("icp.levels: at least one level is needed")
        require_choice("icp", "robust_kernel", self.robust_kernel, ROBUST_KERNELS)
        if not 0 < self.max_pair_angle_rad <= math.pi:
            raise ScannerError("icp.max_pair_angle_rad: must be in (0, pi]")
        check_fields("icp", self)


@dataclass(frozen=True, eq=False)
class Registration:
    """ICP result for a pair: X_TS (target <- source), Open3D's fitness (fraction of source
    points with a correspondence) and inlier RMSE at the finest level, whether the last level
    stopped moving, and Open3D's information matrix (6x6, (rotation, translation) order)."""

    X_TS: np.ndarray
    fitness: float
    inlier_rmse_m: float
    converged: bool
    information: np.ndarray
    n_correspondences: int


@dataclass(frozen=True)
class ViewPair:
    source: int  # positions in the view list, not capture indices; the earlier view
    target: int  # the later one
    kind: str  # "odometry" (consecutive in the tour) or "loop"
    angle_rad: float
    overlap: float


@dataclass(frozen=True, eq=False)
class CloudPyramid:
    """A view's cloud down-sampled per ICP level, with normals facing the camera, in C."""

    levels: tuple[o3d.geometry.PointCloud, ...]
    centroid_C: np.ndarray


def build_pyramid(cloud: FilteredCloud, config: IcpConfig) -> CloudPyramid:
    base = o3d_cloud(cloud.points_C)
    levels = []
    for level in config.levels:
        pc = base.voxel_down_sample(level.voxel_size_m)
        estimate_normals_towards(
            pc,
            np.zeros(3),
            config.normal_radius_factor * level.voxel_size_m,
            config.normal_max_neighbors,
        )
        levels.append(pc)
    centroid = cloud.points_C.mean(axis=0) if len(cloud) else np.zeros(3)
    return CloudPyramid(tuple(levels), centroid)


def _point_to_plane(config: IcpConfig, gate_m: float):
    kernel = ROBUST_KERNELS[config.robust_kernel]
    if kernel is None:
        return _reg.TransformationEstimationPointToPlane()
    return _reg.TransformationEstimationPointToPlane(kernel(config.robust_kernel_scale * gate_m))


def register_pair(
    source: CloudPyramid, target: CloudPyramid, X_TS_init: np.ndarray, config: IcpConfig
) -> Registration:
    """Coarse-to-fine point-to-plane ICP of source onto target from X_TS_init."""
    X_TS = np.asarray(X_TS_init, float)
    result = None
    for k, level in enumerate(config.levels):
        criteria = _reg.ICPConvergenceCriteria(
            config.relative_fitness, config.relative_rmse, level.max_iterations
        )
        result = _reg.registration_icp(
            source.levels[k],
            target.levels[k],
            level.max_correspondence_m,
            X_TS,
            _point_to_plane(config, level.max_correspondence_m),
            criteria,
        )
        X_TS = np.asarray(result.transformation).copy()
    last = config.levels[-1]
    # One more iteration at the finest level tells whether ICP had stopped moving.
    check = _reg.registration_icp(
        source.levels[-1],
        target.levels[-1],
        last.max_correspondence_m,
        X_TS,
        _point_to_plane(config, last.max_correspondence_m),
        _reg.ICPConvergenceCriteria(max_iteration=1),
    )
    step_m = np.linalg.norm(
        transform_points(np.asarray(check.transformation), source.centroid_C[None])
        - transform_points(X_TS, source.centroid_C[None])
    )
    converged = (
        step_m < config.converged_step_m
        and rotation_angle_rad(np.asarray(check.transformation)[:3, :3] @ X_TS[:3, :3].T)
        < config.converged_step_rad
    )
    matches = np.asarray(result.correspondence_set)
    return Registration(
        X_TS,
        float(result.fitness),
        float(result.inlier_rmse),
        bool(converged),
        information_matrix(np.asarray(target.levels[-1].points), matches),
        len(matches),
    )


def information_matrix(target_points: np.ndarray, matches: np.ndarray) -> np.ndarray:
    """Open3D's get_information_matrix_from_point_clouds (6x6, rotation first) from the
    (source, target) index pairs ICP matched at its final pose: the library's function
    would search them again (a tenth of the pairwise ICP time)."""
    q = target_points[np.asarray(matches, int).reshape(-1, 2)[:, 1]]
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    G = np.zeros((3 * len(q), 6))
    G[0::3, 1], G[0::3, 2], G[0::3, 3] = z, -y, 1.0
    G[1::3, 0], G[1::3, 2], G[1::3, 4] = -z, x, 1.0
    G[2::3, 0], G[2::3, 1], G[2::3, 5] = y, -x, 1.0
    return G.T @ G


def edge_check(
    registration: Registration,
    X_TS_prior: np.ndarray,
    source_centroid_C: np.ndarray,
    config: IcpConfig,
) -> str:
    """'' when the edge is trustworthy, else the reason it is pruned."""
    if not registration.fitness >= config.min_fitness:
        return f"fitness {registration.fitness:.2f} < {config.min_fitness:.2f}"
    if not registration.inlier_rmse_m <= config.max_inlier_rmse_m:
        return (
            f"inlier rmse {registration.inlier_rmse_m * 1e3:.2f} mm > "
            f"{config.max_inlier_rmse_m * 1e3:.2f} mm"
        )
    moved_m, turned_rad = correction_at(registration.X_TS, X_TS_prior, source_centroid_C)
    if moved_m > config.max_prior_translation_m or turned_rad > config.max_prior_rotation_rad:
        return (
            f"inconsistent with the kinematic guess ({moved_m * 1e3:.1f} mm, "
            f"{math.degrees(turned_rad):.2f} deg)"
        )
    return ""


def correction_at(X_TS_a: np.ndarray, X_TS_b: np.ndarray, p_S: np.ndarray) -> tuple[float, float]:
    """How far two estimates of X_TS disagree: displacement of the source point p_S (m) and the
    rotation angle (rad). At the cloud's centroid the displacement is what the surface feels,
    unlike the difference of translations, which depends on where the camera origin is."""
    d = transform_points(X_TS_a, p_S[None]) - transform_points(X_TS_b, p_S[None])
    return float(np.linalg.norm(d)), pose_difference(X_TS_a, X_TS_b)[1]


@dataclass(frozen=True, eq=False)
class PairingView:
    """What choosing a view's partners needs of it: its optical axis in W and its coarsest
    ICP level placed in W at the pose the pairs are chosen at (with a k-d tree of it)."""

    z_W: np.ndarray
    coarse_W: np.ndarray
    tree: cKDTree | None


def pairing_view(X_WC: np.ndarray, pyramid: CloudPyramid) -> PairingView:
    points = transform_points(X_WC, np.asarray(pyramid.levels[0].points))
    return PairingView(
        np.asarray(X_WC[:3, 2], float), points, cKDTree(points) if len(points) else None
    )


def partners_among_earlier(
    new: PairingView, earlier: Sequence[PairingView], config: IcpConfig
) -> list[tuple[int, str, float, float]]:
    """The earlier views (positions in `earlier`, in the order the views arrived) the new view
    is registered against: its `max_pairs_per_view` nearest by viewing angle, and the view just
    before it (the odometry edge of the tour), kept when within `max_pair_angle_rad` and at
    least `min_overlap` of the coarser cloud has a neighbour in the other within
    `overlap_distance_m`. Choosing among earlier views only lets each pair be registered as soon
    as its second view arrives; every view still gets its later neighbours as their earlier
    one. Returns (position, kind, angle, overlap)."""
    if not earlier or new.tree is None:
        return []
    z = np.array([v.z_W for v in earlier])
    angle = np.arccos(np.clip(z @ new.z_W, -1.0, 1.0))
    chosen = set(np.argsort(angle, kind="stable")[: config.max_pairs_per_view].tolist())
    chosen.add(len(earlier) - 1)
    out = []
    for k in sorted(chosen):
        other = earlier[k]
        if angle[k] > config.max_pair_angle_rad or other.tree is None:
            continue
        overlap = min(
            _overlap(new.coarse_W, other.tree, config.overlap_distance_m),
            _overlap(other.coarse_W, new.tree, config.overlap_distance_m),
        )
        if overlap >= config.min_overlap:
            kind = "odometry" if k == len(earlier) - 1 else "loop"
            out.append((k, kind, float(angle[k]), overlap))
    return out


def select_pairs(
    X_WC: Sequence[np.ndarray], pyramids: Sequence[CloudPyramid], config: IcpConfig
) -> list[ViewPair]:
    """Overlapping pairs of views listed in the order they arrived (`partners_among_earlier`
    for each in turn): source the earlier view, target the later one (list positions)."""
    seen: list[PairingView] = []
    pairs = []
    for j, (X, pyramid) in enumerate(zip(X_WC, pyramids)):
        new = pairing_view(X, pyramid)
        for i, kind, angle, overlap in partners_among_earlier(new, seen, config):
            pairs.append(ViewPair(i, j, kind, angle, overlap))
        seen.append(new)
    return pairs


def _overlap(points: np.ndarray, tree: cKDTree, distance_m: float) -> float:
    d, _ = tree.query(points, distance_upper_bound=distance_m, workers=query_workers(len(points)))
    return float(np.mean(np.isfinite(d)))


def kinematic_X_TS(X_WC: Sequence[np.ndarray], pair: ViewPair) -> np.ndarray:
    return invert(X_WC[pair.target]) @ X_WC[pair.source]

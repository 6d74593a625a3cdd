"""Aligning the passes of a multi-hanging scan: one rigid transform per pass, found without
truth and verified before it is used.

Within a pass the robot poses register the views; between passes the object was re-hung, so
one rigid transform T (pass frame -> reference frame) is unknown. It is estimated by global
registration (FPFH features, Open3D's RANSAC, several independent runs for several
hypotheses) and by coarse ICP from the centroids under each of the 60 rotations of the
icosahedral group (feature matching alone missed the true turn of a teapot, whose round body
matches its flipped self better than its details do; the start grid found it); each
hypothesis is refined by point-to-plane ICP, and the best one verified:
- overlap: the fraction of the pass's points with a reference point within the inlier distance;
- inlier RMS: the distance of those points, comparable to the stereo noise;
- free space: points of the pass must not lie in space the reference views saw through (in
  front of what a reference camera measured along that ray);
- ambiguity: a distinct hypothesis (another rotation) that scores nearly as well means the
  object's shape cannot tell them apart (symmetry); the alignment is refused then.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from reconstruction.common.checks import check_fields, fraction, integer, positive
from reconstruction.common.kdtree import query_workers
from reconstruction.common.transforms import (
    rotation_angle_rad,
    snapped,
    transform_points,
)
from reconstruction.hangings.free_space import SeenSpace, free_space_violation
from reconstruction.hangings.symmetry import sibling_starts
from reconstruction.registration.pairwise import correction_at


@dataclass(frozen=True)
class AlignmentConfig:
    """Global alignment of passes (`reconstruction.alignment`; lengths in metres).

    voxel_m: the features' sampling (normals over 2.5, FPFH over 5 voxels). runs: independent
    RANSAC runs (hypotheses). coarse_voxel_m / coarse_starts_kept: the sampling of the
    rotation-grid ICP starts and how many of their best fits become hypotheses.
    distinct_rotation_rad: hypotheses closer than this are one.
    min_overlap, max_inlier_rms_m, max_free_space_violation: verification limits.
    inlier_distance_m: a point within this of the reference counts as overlapping.
    free_space_margin_m: how far in front of a measured surface a point must lie to count as
    seen-through space. max_ambiguity: a distinct runner-up scoring above this fraction of the
    best makes the alignment ambiguous. min_colour_agreement: the least correlation of the grey
    values of matched points (the texture must agree, not only the shape).
    """

    voxel_m: float = positive(0.003)
    runs: int = integer(8)
    coarse_voxel_m: float = positive(0.008)
    coarse_starts_kept: int = integer(8)
    # 20,000: the same alignments as 100,000 on the two-hanging bunny, spot and teapot (within
    # 0.02 mm, 0.002 deg) in half the time (31 -> 22 s, 31 -> 17 s, 26 -> 11 s a pass); RANSAC
    # is one of three sources of hypotheses, beside FGR and the rotation grid.
    ransac_iterations: int = integer(20_000)
    distinct_rotation_rad: float = positive(math.radians(10.0))
    inlier_distance_m: float = positive(0.0015)
    min_overlap: float = fraction(0.2)
    max_inlier_rms_m: float = positive(0.001)
    free_space_margin_m: float = positive(0.003)
    max_free_space_violation: float = fraction(0.1)
    max_ambiguity: float = fraction(0.9)
    # Measured (grey correlation of matched points, 1280x960): the bunny's true alignment
    # 0.31, the bracket's 0.36 (640x480); a teapot turned by 180 deg (its body fits) 0.11.
    min_colour_agreement: float = fraction(0.2)

    def __post_init__(self) -> None:
        check_fields("alignment", self)


@dataclass(frozen=True, eq=False)
class PassAlignment:
    """The transform of one pass into the reference frame and the figures that verified it."""

    hanging: int
    T: np.ndarray  # 4x4: points of the pass -> the reference frame
    overlap: float
    inlier_rms_m: float
    free_space_violation: float
    colour_agreement: float  # correlation of matched points' grey values (1: not checked)
    ambiguity: float  # runner-up score / best score (0: no distinct runner-up)
    hypotheses: int
    failures: tuple[str, ...]  # the checks that failed (empty: verified)
    # The known turn (a turntable's) refined and verified without the search for hypotheses.
    from_known_turn: bool = False
    # The alignment the scan's quick model found on the same captures (its search ranked every
    # hypothesis), refined and verified again here without a second search.
    from_earlier: bool = False

    @property
    def verified(self) -> bool:
        return not self.failures


def prepared_cloud(points: np.ndarray, voxel: float):
    """The points on a grid of `voxel`, with normals over 2.5 voxels (Open3D)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    down = cloud.voxel_down_sample(voxel)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    return down


def fpfh_features(down, voxel: float):
    """FPFH features of a `prepared_cloud` over 5 voxels."""
    import open3d as o3d

    return o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    )


def prepared_features(points: np.ndarray, voxel: float):
    down = prepared_cloud(points, voxel)
    return down, fpfh_features(down, voxel)


def feature_hypotheses(source, target, src_f, tgt_f, config: AlignmentConfig) -> list[np.ndarray]:
    import open3d as o3d

    reg = o3d.pipelines.registration
    distance = 1.5 * config.voxel_m
    fgr = reg.registration_fgr_based_on_feature_matching(
        source,
        target,
        src_f,
        tgt_f,
        reg.FastGlobalRegistrationOption(maximum_correspondence_distance=distance),
    )
    out = [np.asarray(fgr.transformation)]
    # Matching the features took 50-95 % of each run when every run matched them anew (what
    # registration_ransac_based_on_feature_matching does); matched once per filter, the runs
    # give the same transforms.
    matches: dict[bool, object] = {}
    for run in range(config.runs):
        # Each run its own seed and every other one without the mutual filter (more, noisier
        # correspondences): different samples, different hypotheses.
        mutual = run % 2 == 0
        if mutual not in matches:
            matches[mutual] = reg.correspondences_from_features(src_f, tgt_f, mutual)
        o3d.utility.random.seed(1000 + run)
        result = reg.registration_ransac_based_on_correspondence(
            source,
            target,
            matches[mutual],
            distance,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [
                reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                reg.CorrespondenceCheckerBasedOnDistance(distance),
            ],
            reg.RANSACConvergenceCriteria(config.ransac_iterations, 0.9999),
        )
        out.append(np.asarray(result.transformation))
    return out


def rotation_grid_hypotheses(
    source, target, config: AlignmentConfig, textured_score=None
) -> list[np.ndarray]:
    """Coarse point-to-plane ICP from the centroids under each rotation of the icosahedral
    group (no two rotations of a 3D object are more than ~45 deg from one of them: inside
    ICP's basin with wide gates); the best fits by overlap and, given `textured_score(T)`,
    also the best by it (without repeats)."""
    import open3d as o3d
    from scipy.spatial.transform import Rotation

    voxel = config.coarse_voxel_m
    src, tgt = source.voxel_down_sample(voxel), target.voxel_down_sample(voxel)
    for cloud in (src, tgt):
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    c_src = np.asarray(src.points).mean(axis=0)
    c_tgt = np.asarray(tgt.points).mean(axis=0)
    fits = []
    for R in Rotation.create_group("I").as_matrix():
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, c_tgt - R @ c_src
        result = icp_coarse_to_fine(src, tgt, T, (5 * voxel, 2.5 * voxel, 1.25 * voxel), 30)
        fits.append((result.fitness, np.asarray(result.transformation)))
    kept = sorted(range(len(fits)), key=lambda k: -fits[k][0])[: config.coarse_starts_kept]
    if textured_score is not None:
        # A shape with a symmetry (a vase about its axis, an ellipsoid turned by half a turn)
        # fits in many orientations equally well, and which of them the overlap keeps is
        # chance: the true one was seen ranked 9th of 60. Only its texture sets it apart.
        scores = [textured_score(T) for _, T in fits]
        by_texture = sorted(range(len(fits)), key=lambda k: -scores[k])
        kept += [k for k in by_texture[: config.coarse_starts_kept] if k not in kept]
    return [fits[k][1] for k in kept]


def _refine(source, target, T0: np.ndarray, config: AlignmentConfig) -> np.ndarray:
    gates_m = (3 * config.voxel_m, config.voxel_m, config.inlier_distance_m)
    return np.asarray(icp_coarse_to_fine(source, target, T0, gates_m, 50).transformation)


def icp_coarse_to_fine(source, target, T0: np.ndarray, gates_m, max_iterations: int):
    """Point-to-plane ICP at each correspondence gate in turn, each from the previous fit;
    Open3D's result of the last (its transformation maps source points into the target)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    T = T0
    for distance in gates_m:
        result = reg.registration_icp(
            source,
            target,
            distance,
            T,
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(max_iteration=max_iterations),
        )
        T = result.transformation
    return result


@dataclass(frozen=True)
class _Fit:
    overlap: float
    inlier_rms_m: float
    colour_agreement: float


def _fit(points, grey, tree, reference_grey, distance: float) -> _Fit:
    """Overlap, inlier RMS, and the correlation of the grey values of matched points: a
    rotation that fits the shape but not the texture (a symmetric shape flipped) correlates
    near 0, the true one clearly above."""
    d, idx = tree.query(points, distance_upper_bound=distance, workers=query_workers(len(points)))
    inliers = np.isfinite(d)
    if inliers.sum() < 10:
        return _Fit(float(inliers.mean()), math.inf, 0.0)
    a, b = grey[inliers], reference_grey[idx[inliers]]
    spread = a.std() * b.std()
    agreement = float(np.mean((a - a.mean()) * (b - b.mean())) / spread) if spread > 0 else 0.0
    rms = float(np.sqrt(np.mean(d[inliers] ** 2)))
    return _Fit(float(inliers.mean()), rms, agreement)


# (m at the source's centre, rad) within which two starts lie in one basin of the refining ICP
# (whose first gate is 9 mm). Measured on three two-hanging scans, starts within 3 mm / 2 deg
# of each other ended within 1 um where they led to the chosen alignment; two that led to a
# wrong orientation (which only sets the runner-up score) ended 0.8 mm apart.
SAME_START = (0.002, math.radians(1.0))
# Within which two refined hypotheses are one fit: far below what their scores resolve.
SAME_FIT = (2e-5, math.radians(0.005))


# How far the refined fit of a known turn may end from the turn itself (m at the source's
# centre, rad): the nominal axis is up to a millimetre and a tenth of a degree off the true one
# (the turntable's mounting), the fit another millimetre off; farther, the fit has slid along
# the shape, not refined the turn. The same bound holds an earlier alignment of the same
# captures, whose poses differ from the final ones by the mount's correction (a millimetre).
START_DRIFT = (0.005, math.radians(1.0))


def _same_pose(A: np.ndarray, B: np.ndarray, centre: np.ndarray, within) -> bool:
    moved_m, turned_rad = correction_at(A, B, centre)
    return moved_m <= within[0] and turned_rad <= within[1]


def _score(fit: _Fit, violation: float) -> float:
    """Overlap with the reference, discounted by the share of seen-through space and by how
    little the texture agrees."""
    return fit.overlap * (1.0 - violation) * max(fit.colour_agreement, 0.0)


def align_pass(
    hanging: int,
    points: np.ndarray,
    reference: np.ndarray,
    seen: SeenSpace,
    config: AlignmentConfig = AlignmentConfig(),
    colors: np.ndarray | None = None,
    reference_colors: np.ndarray | None = None,
    start: np.ndarray | None = None,
    earlier: PassAlignment | None = None,
) -> PassAlignment:
    """T that puts `points` (a pass's fused cloud, colours (N, 3) uint8) onto `reference`,
    with its verification. Without colours the texture check is left out. `start`: a known
    guess of T (a turntable's turn): refined and verified first, the search for hypotheses
    runs only when it does not verify. A known turn needs no ambiguity check: the turntable,
    not the shape, tells the symmetric orientations apart.

    `earlier`: this pass's verified alignment found by a search on the same captures at
    slightly other poses (the scan's quick model, before the mount was corrected on every
    pass): refined from, and verified as any fit (the texture included) with the ambiguity
    that search measured over all its hypotheses; the search runs again only when the fit
    fails or slides away from it."""
    from scipy.spatial import cKDTree

    # The features only where the search runs: a known turn or an earlier alignment that
    # verifies is refined without them.
    source = prepared_cloud(points, config.voxel_m)
    target = prepared_cloud(reference, config.voxel_m)
    tree = cKDTree(reference)
    textured = colors is not None and reference_colors is not None
    grey = np.asarray(colors, float).mean(axis=1) if textured else np.zeros(len(points))
    ref_grey = np.asarray(reference_colors, float).mean(axis=1) if textured else None
    sample = np.asarray(source.points)
    centre = sample.mean(axis=0)
    candidates, refined_from = [], []

    def evaluate(T: np.ndarray) -> tuple:
        fit = _fit(
            transform_points(T, points),
            grey,
            tree,
            ref_grey if textured else np.zeros(len(reference)),
            config.inlier_distance_m,
        )
        if not textured:
            fit = _Fit(fit.overlap, fit.inlier_rms_m, 1.0)
        violation = free_space_violation(
            transform_points(T, sample), seen, config.free_space_margin_m
        )
        return _score(fit, violation), T, fit, violation

    if start is not None:
        known = evaluate(_refine(source, target, np.asarray(start, float), config))
        # The turn is measured, not guessed: the texture check (which tells a symmetric
        # shape's turns apart) is not needed, and would fail where the light, fixed in the
        # cell, shades the overlap differently once the object has turned; the fit must stay
        # near the turn instead.
        near = _same_pose(known[1], np.asarray(start, float), centre, START_DRIFT)
        if near and not _failures(known[2], known[3], 0.0, False, config):
            return _alignment(hanging, known[1], known[2], known[3], 0.0, 1, (), True)
        candidates.append(known)
    elif earlier is not None and earlier.verified:
        again = evaluate(_refine(source, target, np.asarray(earlier.T, float), config))
        near = _same_pose(again[1], np.asarray(earlier.T, float), centre, START_DRIFT)
        if near and not _failures(again[2], again[3], earlier.ambiguity, textured, config):
            return replace(
                _alignment(hanging, again[1], again[2], again[3], earlier.ambiguity, 1, (), False),
                from_earlier=True,
            )
        candidates.append(again)
    src_f, tgt_f = fpfh_features(source, config.voxel_m), fpfh_features(target, config.voxel_m)
    starts = feature_hypotheses(source, target, src_f, tgt_f, config)
    textured_score = None
    if textured:
        every = max(len(points) // 20_000, 1)  # a subsample ranks the coarse fits as well

        def textured_score(T: np.ndarray) -> float:
            fit = _fit(
                transform_points(T, points[::every]),
                grey[::every],
                tree,
                ref_grey,
                config.voxel_m,  # looser than the inlier distance: the fits are coarse
            )
            return fit.overlap * max(fit.colour_agreement, 0.0)

    def consider(T0: np.ndarray) -> None:
        # Hypotheses often agree (RANSAC runs finding the same answer): one that starts, or
        # ends, where an earlier one did is that one again, and costs no second evaluation.
        same = next((c for S, c in refined_from if _same_pose(T0, S, centre, SAME_START)), None)
        T = _refine(source, target, T0, config) if same is None else same[1]
        same = same or next((c for c in candidates if _same_pose(T, c[1], centre, SAME_FIT)), None)
        if same is None:
            same = evaluate(T)
        refined_from.append((T0, same))
        candidates.append(same)

    for T0 in starts + rotation_grid_hypotheses(source, target, config, textured_score):
        consider(T0)
    # The shape's symmetric orientations that no generator reached: the texture decides
    # between them, and a runner-up among them makes an untextured shape ambiguous.
    distinct = {id(c): c for c in candidates}.values()
    shape_fits = [(c[2].overlap * (1.0 - c[3]), c[1]) for c in distinct]
    for T0 in sibling_starts(shape_fits, config.distinct_rotation_rad):
        consider(T0)
    candidates.sort(key=lambda c: -c[0])
    best_score, T, fit, violation = candidates[0]
    runner_up = next(
        (
            c[0]
            for c in candidates[1:]
            if rotation_angle_rad(c[1][:3, :3].T @ T[:3, :3]) > config.distinct_rotation_rad
        ),
        0.0,
    )
    ambiguity = runner_up / best_score if best_score > 0 else 1.0
    failures = _failures(fit, violation, ambiguity, textured, config)
    return _alignment(hanging, T, fit, violation, ambiguity, len(candidates), failures, False)


def _failures(
    fit: _Fit, violation: float, ambiguity: float, textured: bool, config: AlignmentConfig
) -> tuple[str, ...]:
    """The verification checks a fit fails (empty: verified)."""
    overlap, rms = fit.overlap, fit.inlier_rms_m
    failures = []
    if overlap < config.min_overlap:
        failures.append(f"overlap {overlap:.2f} (need >= {config.min_overlap:g})")
    if rms > config.max_inlier_rms_m:
        failures.append(
            f"inlier RMS {1e3 * rms:.2f} mm (limit {1e3 * config.max_inlier_rms_m:g} mm)"
        )
    if violation > config.max_free_space_violation:
        failures.append(
            f"{100 * violation:.1f} % of the points in space the other views saw through "
            f"(limit {100 * config.max_free_space_violation:g} %)"
        )
    if textured and fit.colour_agreement < config.min_colour_agreement:
        failures.append(
            f"the texture does not match (correlation {fit.colour_agreement:.2f}, need >= "
            f"{config.min_colour_agreement:g}): another object, or a symmetric shape turned"
        )
    if ambiguity > config.max_ambiguity:
        failures.append(
            f"ambiguous: another orientation fits {100 * ambiguity:.0f} % as well (a symmetric "
            "shape; scan a further hanging)"
        )
    return tuple(failures)


def _alignment(hanging, T, fit, violation, ambiguity, hypotheses, failures, known) -> PassAlignment:
    return PassAlignment(
        hanging,
        # Open3D's ICP sums in no fixed order: two runs end apart in the last bits, and the
        # Poisson octree of the merged hangings turns that into another mesh. On a 1e-9 grid
        # (rad, m) the same captures give the same pass transform, and so the same model.
        snapped(T, np.eye(4)),
        fit.overlap,
        fit.inlier_rms_m,
        violation,
        fit.colour_agreement,
        ambiguity,
        hypotheses,
        tuple(failures),
        known,
    )


def alignment_error(
    T: np.ndarray, T_true: np.ndarray, object_points: Sequence[np.ndarray]
) -> tuple[float, float]:
    """(largest displacement over the object's points in m, rotation error in rad) of T."""
    pts = np.asarray(object_points)
    d = np.linalg.norm(transform_points(T, pts) - transform_points(T_true, pts), axis=1)
    return float(d.max()), rotation_angle_rad(T[:3, :3].T @ T_true[:3, :3])

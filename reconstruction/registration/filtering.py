"""Per-view cloud filtering: region of interest, voxel down-sampling, outliers, caller's removal.

The kept points stay in the camera frame C: every later stage re-poses them with its own X_WC
(kinematic, ICP-refined, or with a corrected hand-eye), so filtering runs once per view. The
region of interest and the caller's `remove_points` hook see the points in W at the pose given
here (the kinematic one), which is why the region has a margin: a few mm of hand-eye error moves
the cloud by up to ~10 mm at 0.5 m (1 deg of rotation alone is 8.7 mm).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import transform_points
from reconstruction.registration.views import ViewCloud

# points_W (N, 3), view index -> keep mask (N,) bool. The robots package implements it with the
# Drake geometry of the robot, tool, rod and cell at the view's recorded configuration.
RemovePoints = Callable[[np.ndarray, int], np.ndarray]

ROI_SHAPES = ("none", "sphere", "box")


@dataclass(frozen=True)
class RegionOfInterest:
    """Where the object can be, in W. `center_m` None: no crop (the caller knows the centre)."""

    shape: str = "sphere"
    center_m: tuple[float, float, float] | None = None
    # Default: a 0.2 m object (bounding sphere radius 0.173 m) plus 27 mm for pose error.
    radius_m: float = positive(0.2)
    half_extent_m: tuple[float, float, float] = (0.15, 0.15, 0.15)

    def __post_init__(self) -> None:
        if self.shape not in ROI_SHAPES:
            raise ScannerError(f"roi.shape: '{self.shape}' is not one of {', '.join(ROI_SHAPES)}")
        if self.center_m is not None and (
            len(self.center_m) != 3 or not all(math.isfinite(c) for c in self.center_m)
        ):
            raise ScannerError(f"roi.center_m: expected three finite numbers, got {self.center_m}")
        check_fields("roi", self)
        if len(self.half_extent_m) != 3 or not all(h > 0 for h in self.half_extent_m):
            raise ScannerError(
                f"roi.half_extent_m: three positive numbers, got {self.half_extent_m}"
            )

    def contains(self, p_W: np.ndarray) -> np.ndarray:
        if self.shape == "none" or self.center_m is None:
            return np.ones(len(p_W), bool)
        d = p_W - np.asarray(self.center_m)
        if self.shape == "sphere":
            return np.einsum("ij,ij->i", d, d) <= self.radius_m**2
        return np.all(np.abs(d) <= np.asarray(self.half_extent_m), axis=1)


@dataclass(frozen=True)
class FilterConfig:
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)
    # 1 mm voxels: the pixel footprint is 0.38 mm at 0.5 m (f = 1320 px), so each voxel averages
    # ~7 stereo points (median depth noise ~0.2 mm) while every later stage (finest ICP
    # level, hand-eye targets, fused cloud) works at 1 mm anyway.
    voxel_size_m: float = positive(0.001)
    # 0 disables the statistical outlier removal.
    outlier_neighbors: int = integer(20, minimum=0)
    outlier_std_ratio: float = positive(2.5)
    # Normals from a 3 mm neighbourhood (~25 points): wide enough to average the depth noise,
    # narrow enough for the objects' curvature radii (>= ~10 mm on the built-ins).
    normal_radius_m: float = positive(0.003)
    normal_max_neighbors: int = integer(30, minimum=3)
    min_points: int = integer(200, minimum=3)

    def __post_init__(self) -> None:
        check_fields("filter", self)


@dataclass(frozen=True)
class FilterCounts:
    """Points of one view: input, then left after each step in order."""

    input: int
    after_roi: int
    after_voxel: int
    after_hook: int
    after_outliers: int


@dataclass(frozen=True, eq=False)
class FilteredCloud:
    """One view's kept points in the camera frame C, with colours and normals facing the camera."""

    index: int
    points_C: np.ndarray
    colors: np.ndarray
    normals_C: np.ndarray
    counts: FilterCounts

    def __post_init__(self) -> None:
        for a in (self.points_C, self.colors, self.normals_C):
            a.setflags(write=False)

    def __len__(self) -> int:
        return len(self.points_C)


def o3d_cloud(
    points: np.ndarray, normals: np.ndarray | None = None, colors: np.ndarray | None = None
) -> o3d.geometry.PointCloud:
    """An Open3D cloud from (N, 3) arrays (copied: Open3D rejects read-only arrays); colours
    uint8 0-255 or float 0-1."""
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(points, np.float64)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.array(normals, np.float64))
    if colors is not None:
        c = np.array(colors, np.float64)
        pc.colors = o3d.utility.Vector3dVector(c / 255.0 if colors.dtype == np.uint8 else c)
    return pc


def estimate_normals_towards(
    pc: o3d.geometry.PointCloud, viewpoint: np.ndarray, radius_m: float, max_nn: int
) -> None:
    """Normals in place, each flipped to face `viewpoint` (the camera saw the outside)."""
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=max_nn))
    pc.orient_normals_towards_camera_location(np.asarray(viewpoint, np.float64))


def apply_hook(remove_points: RemovePoints, p_W: np.ndarray, view_index: int) -> np.ndarray:
    """The caller's keep mask, checked: a wrong shape is a programming error, so it raises."""
    keep = np.asarray(remove_points(p_W, view_index))
    if keep.shape != (len(p_W),) or keep.dtype != bool:
        raise TypeError(
            f"remove_points must return a boolean keep mask of shape ({len(p_W)},), "
            f"got {keep.dtype} {keep.shape}"
        )
    return keep


def filter_view(
    index: int,
    points_C: np.ndarray,
    colors: np.ndarray,
    X_WC: np.ndarray,
    config: FilterConfig,
    remove_points: RemovePoints | None = None,
) -> FilteredCloud:
    """Crop to the region of interest (in W at X_WC), voxel down-sample (centroid of each voxel,
    colours averaged), drop what `remove_points` rejects, remove statistical outliers, and
    estimate normals facing the camera. Non-finite points are dropped first."""
    points_C = np.asarray(points_C, np.float64)
    colors = np.asarray(colors)
    if points_C.ndim != 2 or points_C.shape[1] != 3 or colors.shape != points_C.shape:
        raise ScannerError(
            f"view {index}: points (N, 3) and colours (N, 3) expected, got "
            f"{points_C.shape} and {colors.shape}"
        )
    n_input = len(points_C)
    finite = np.all(np.isfinite(points_C), axis=1)
    points_C, colors = points_C[finite], colors[finite]
    inside = config.roi.contains(transform_points(X_WC, points_C))
    points_C, colors = points_C[inside], colors[inside]
    n_roi = len(points_C)

    pc = o3d_cloud(points_C, colors=colors).voxel_down_sample(config.voxel_size_m)
    points_C = np.asarray(pc.points)
    colors = np.asarray(pc.colors)
    n_voxel = len(points_C)

    if remove_points is not None and n_voxel:
        keep = apply_hook(remove_points, transform_points(X_WC, points_C), index)
        points_C, colors = points_C[keep], colors[keep]
    n_hook = len(points_C)

    pc = o3d_cloud(points_C, colors=colors)
    if config.outlier_neighbors > 0 and len(pc.points) > config.outlier_neighbors:
        pc, _ = pc.remove_statistical_outlier(config.outlier_neighbors, config.outlier_std_ratio)
    n_out = len(pc.points)
    if n_out >= 3:
        estimate_normals_towards(
            pc, np.zeros(3), config.normal_radius_m, config.normal_max_neighbors
        )
    normals = np.asarray(pc.normals) if pc.has_normals() else np.zeros((n_out, 3))
    return FilteredCloud(
        index,
        np.asarray(pc.points).copy(),
        np.clip(np.round(np.asarray(pc.colors) * 255.0), 0, 255).astype(np.uint8),
        normals.copy(),
        FilterCounts(n_input, n_roi, n_voxel, n_hook, n_out),
    )


def refiltered(
    cloud: FilteredCloud, X_WC: np.ndarray, remove_points: RemovePoints
) -> FilteredCloud:
    """The cloud without the points `remove_points` rejects at another pose of the view (its
    final one: the rod and the robot are where the corrected pose puts them, while the pose
    the view was filtered with can be a centimetre off)."""
    if not len(cloud):
        return cloud
    keep = apply_hook(remove_points, transform_points(X_WC, cloud.points_C), cloud.index)
    if keep.all():
        return cloud
    dropped = int((~keep).sum())
    counts = cloud.counts
    return FilteredCloud(
        cloud.index,
        cloud.points_C[keep].copy(),
        cloud.colors[keep].copy(),
        cloud.normals_C[keep].copy(),
        FilterCounts(
            counts.input,
            counts.after_roi,
            counts.after_voxel,
            counts.after_hook - dropped,
            counts.after_outliers - dropped,
        ),
    )


# Views processed at a time (stereo, filtering): SGBM keeps both cores of the target machine
# busy, the filters after it only one, so a second view's work fills the other core.
VIEW_THREADS = 2


def filter_views(
    views: Sequence[ViewCloud],
    X_FC_nominal: np.ndarray,
    config: FilterConfig,
    remove_points: RemovePoints | None = None,
    done: Mapping[int, FilteredCloud] | None = None,
) -> tuple[list[ViewCloud], list[FilteredCloud], list[tuple[int, str]]]:
    """Filter every view at its kinematic pose; views left with too few points are skipped
    (reported), never fatal. Returns the kept views, their clouds, and (index, reason) skips.
    `done`: clouds of some views already filtered exactly so (streamed during the scan)."""
    kept_views, clouds, skipped = [], [], []
    done = done or {}

    def one(view: ViewCloud) -> FilteredCloud:
        if view.index in done:
            return done[view.index]
        return filter_view(
            view.index,
            view.points_C,
            view.colors,
            view.X_WF @ X_FC_nominal,
            config,
            remove_points,
        )

    with ThreadPoolExecutor(max_workers=VIEW_THREADS) as pool:
        filtered = list(pool.map(one, views))
    for view, cloud in zip(views, filtered):
        if len(cloud) < config.min_points:
            skipped.append((view.index, f"{len(cloud)} points after filtering"))
            continue
        kept_views.append(view)
        clouds.append(cloud)
    return kept_views, clouds, skipped

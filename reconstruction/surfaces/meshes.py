"""Surfaces from the posed views: the fused cloud, TSDF fusion of depth maps, Poisson and ball
pivoting meshes, mesh cleaning, and file output (metres, world frame W).

Poisson closes every surface, including the unseen side of the object (the RX60 sees ~10 % of
the viewing sphere), so its mesh is trimmed twice: vertices of low Poisson density (few samples
nearby, the usual criterion) and vertices farther than `poisson_max_distance_m` from any fused
point (what density alone misses when the extrapolated cap is large).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from reconstruction.common.checks import (
    check_fields,
    integer,
    non_negative,
    positive,
    require_choice,
)
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, rotate_vectors, transform_points
from reconstruction.registration.filtering import (
    FilteredCloud,
    RegionOfInterest,
    RemovePoints,
    apply_hook,
    o3d_cloud,
)
from reconstruction.registration.views import DepthImage
from reconstruction.surfaces.normals import local_planes, off_surface
from reconstruction.surfaces.poisson_solver import solve_poisson_apart
from reconstruction.surfaces.rbf import RBF_KERNELS, RbfParams, rbf_surface
from reconstruction.surfaces.topology import (
    canonical_order,
    clean_mesh,
    fill_small_holes,
    triangle_components,
)

MESH_SUFFIXES = (".ply", ".obj", ".stl")
# The depth maps' robot/cell removal decides per cell of this size, not per pixel: the pixels
# of a 1 mm cell (~7 at 0.5 m) are one fused voxel anyway, and the removal margin is 10 mm.
# On the 24-view bunny the removal took 2.8 of the TSDF's 6.4 s per pixel.
HOOK_CELL_M = 0.001


@dataclass(frozen=True)
class SurfaceConfig:
    methods: tuple[str, ...] = ("poisson", "tsdf")
    # 1 mm: Poisson from 0.5 mm points was 4x slower and no more accurate on the synthetic
    # pebble (accuracy p90 0.08 mm either way).
    fused_voxel_size_m: float = positive(0.001)
    # The fused cloud's local planes (`fused_normals`, 0 = off) over this radius give its
    # normals, and points farther from theirs than fused_outlier_sigmas robust standard
    # deviations of all such distances are dropped (0 = none). Measured on the 24-view bunny,
    # observed Chamfer (mm): views' normals 0.1745; planes over 3 / 4 mm 0.1746 / 0.1704;
    # with the drop at 2.5 sigma (~0.7 mm, ~8 % of the points) 0.1592; fandisk 0.2276 -> 0.2168,
    # teapot 0.1838 (planes alone) -> 0.1736, spot 0.1781.
    fused_normal_radius_m: float = non_negative(0.004)
    fused_outlier_sigmas: float = non_negative(2.5)
    # Depth 8: cells of about 1 mm over a 0.2 m object, the fused cloud's own spacing. Depth 9
    # took twice as long (12 s of a 24-view scan) for nothing measurable: Chamfer on the
    # observed surface (mm, depth 8 / 9) vase 0.264 / 0.267, bunny 0.242 / 0.234, fandisk
    # 0.271 / 0.264, teapot 0.226 / 0.224, spot 0.463 / 0.463, bracket 0.90 / 1.39.
    poisson_depth: int = 8
    # Density trimming (2 % in a prototype of this pipeline) punches holes in well-covered surfaces
    # too (356 holes on a fully covered synthetic pebble); trimming by distance to the data
    # removes what Poisson invents on the unseen side and keeps observed surfaces closed.
    poisson_density_quantile: float = 0.0
    # 1.25 mm: a vertex of a surface the data cover lies within ~0.9 mm of a 1 mm fused point,
    # while the rim Poisson extrapolates past the data's edge is where its error is largest
    # (0.9 mm mean within 2 mm of the open boundary on the bunny). Observed Chamfer (mm) at
    # 2 / 1.5 / 1.25 / 1 mm: bunny 0.242 / 0.226 / 0.220 / 0.218, teapot 0.228 / 0.212 / 0.204
    # / 0.197, fandisk 0.270 / 0.265 / 0.265 / 0.265, spot 0.463 / 0.457 / 0.458 / 0.461; the
    # whole-object completeness at 2 mm loses 0.4-1.3 points from 2 to 1.25 mm.
    poisson_max_distance_m: float = positive(0.00125)
    # 1 mm voxels: ~0.2 mm Chamfer in < 1 s in a prototype of this pipeline (24 views).
    tsdf_voxel_size_m: float = positive(0.001)
    tsdf_truncation_voxels: float = positive(4.0)
    tsdf_depth_max_m: float = positive(1.5)
    tsdf_min_views: int = integer(1)  # views that must have seen a voxel for it to be meshed
    tsdf_block_count: int = integer(40000)
    ball_pivoting_radii_m: tuple[float, ...] = (0.001, 0.002, 0.004)
    # Components with fewer triangles than this fraction of the largest one are debris.
    min_component_fraction: float = 0.02
    # Holes whose boundary fits in a sphere of this radius are closed: at 1 mm fused voxels the
    # data cannot show a hole that small, so it is a meshing artefact (Poisson leaves such
    # loops where its trimming cuts a single triangle out), not a feature of the object.
    # 1.5 mm: Poisson's cells are ~1.06 mm at depth 8 on a 0.2 m object, and a hole bounded
    # by four of their edges reached 1.01 mm (a two-hanging closed model left open at 1 mm).
    fill_holes_max_radius_m: float = non_negative(0.0015)
    # RBF implicit surface ("rbf", reconstruction/surface_rbf.py). Centres: the fused cloud
    # thinned to 2 mm voxels (at most rbf_max_centres; the spacing grows beyond), each with
    # points rbf_offset_m along and against its normal. Measured on the 24-view bunny
    # (scripts/bench_rbf.py, observed Chamfer mm, Poisson 0.242): these defaults 0.288 in
    # ~22 s; smoothing 0.1 / 1 / 5: 0.340 / 0.295 / 0.300; offset 1 / 2 mm: 0.295 / 0.329;
    # spacing 1.5 / 3 mm: 0.301 / 0.305; 1 mm grid 0.307 in 60 s; 32 neighbours 0.293 in 66 s;
    # the linear kernel 0.292 in 16 s.
    rbf_centre_spacing_m: float = positive(0.002)
    rbf_max_centres: int = integer(20000, minimum=100)
    rbf_offset_m: float = positive(0.0005)
    rbf_kernel: str = "thin_plate_spline"
    rbf_neighbors: int = integer(16, minimum=4)
    # scipy RBFInterpolator's smoothing, in units of the centre spacing: 0 interpolates the
    # stereo noise.
    rbf_smoothing: float = non_negative(2.0)
    rbf_voxel_size_m: float = positive(0.0015)  # marching-cubes grid
    rbf_max_distance_m: float = positive(0.002)  # triangles farther from the data are cut

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in SURFACE_METHODS]
        if unknown:
            raise ScannerError(
                f"surfaces.methods: unknown {', '.join(unknown)}; valid: "
                f"{', '.join(SURFACE_METHODS)}"
            )
        check_fields("surfaces", self)
        require_choice("surfaces", "rbf_kernel", self.rbf_kernel, RBF_KERNELS)
        if not 0 <= self.poisson_density_quantile < 1 or not 0 <= self.min_component_fraction < 1:
            raise ScannerError(
                "surfaces: poisson_density_quantile and min_component_fraction in [0, 1)"
            )
        if not 4 <= self.poisson_depth <= 12:
            raise ScannerError("surfaces.poisson_depth: between 4 and 12")
        if not self.ball_pivoting_radii_m or min(self.ball_pivoting_radii_m) <= 0:
            raise ScannerError("surfaces.ball_pivoting_radii_m: positive radii")


@dataclass(frozen=True, eq=False)
class FusedCloud:
    """All views' points in W (N, 3), colours uint8, unit normals facing the cameras."""

    points_W: np.ndarray
    colors: np.ndarray
    normals_W: np.ndarray

    def __len__(self) -> int:
        return len(self.points_W)


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """A triangle mesh in W: vertices (V, 3) m, triangles (M, 3), vertex colours (V, 3) uint8
    or None."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray | None = None
    filled_holes: int = 0  # small holes closed by `finish_mesh` (filled, not seen)
    filled_area_m2: float = 0.0  # their area

    def to_open3d(self) -> o3d.geometry.TriangleMesh:
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.array(self.vertices, np.float64)),
            o3d.utility.Vector3iVector(np.array(self.triangles, np.int32)),
        )
        if self.colors is not None:
            mesh.vertex_colors = o3d.utility.Vector3dVector(np.array(self.colors) / 255.0)
        return mesh


@dataclass(frozen=True, eq=False)
class DepthView:
    """A depth map with the camera pose to integrate it at."""

    depth: DepthImage
    X_WC: np.ndarray
    index: int


def _from_open3d(
    name: str, mesh: o3d.geometry.TriangleMesh, filled_holes: int, filled_area_m2: float
) -> SurfaceMesh:
    colors = (
        np.clip(np.round(np.asarray(mesh.vertex_colors) * 255), 0, 255).astype(np.uint8)
        if mesh.has_vertex_colors()
        else None
    )
    return SurfaceMesh(
        name,
        np.asarray(mesh.vertices).copy(),
        np.asarray(mesh.triangles).copy(),
        colors,
        filled_holes,
        filled_area_m2,
    )


def fuse_clouds(
    clouds: Sequence[FilteredCloud], X_WC: Sequence[np.ndarray], voxel_size_m: float
) -> FusedCloud:
    """Every view moved to W by its X_WC, merged, and voxel-averaged (normals re-normalised)."""
    points = np.vstack([transform_points(X, c.points_C) for c, X in zip(clouds, X_WC)])
    normals = np.vstack([rotate_vectors(X, c.normals_C) for c, X in zip(clouds, X_WC)])
    colors = np.vstack([c.colors for c in clouds])
    pc = o3d_cloud(points, normals, colors).voxel_down_sample(voxel_size_m)
    n = np.asarray(pc.normals)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return FusedCloud(
        np.asarray(pc.points).copy(),
        np.clip(np.round(np.asarray(pc.colors) * 255), 0, 255).astype(np.uint8),
        n,
    )


def refine_fused(fused: FusedCloud, radius_m: float, outlier_sigmas: float) -> FusedCloud:
    """The fused cloud with its local planes' normals, without the points far off them."""
    if radius_m <= 0 or len(fused) == 0:
        return fused
    planes = local_planes(fused.points_W, fused.normals_W, radius_m)
    keep = ~off_surface(planes.residuals_m, outlier_sigmas)
    return FusedCloud(fused.points_W[keep], fused.colors[keep], planes.normals[keep])


def finish_mesh(name: str, mesh: o3d.geometry.TriangleMesh, config: SurfaceConfig) -> SurfaceMesh:
    """Clean the mesh and close its small holes; the count of closed holes goes with it."""
    clean_mesh(mesh, config.min_component_fraction)
    area = mesh.get_surface_area()
    filled = fill_small_holes(mesh, config.fill_holes_max_radius_m)
    return _from_open3d(name, mesh, filled, max(mesh.get_surface_area() - area, 0.0))


@dataclass(frozen=True, eq=False)
class SurfaceInput:
    """What a surface is built from: the fused cloud in W, the depth maps at their poses (TSDF),
    and the region of interest and the caller's point filter (applied to the depth maps as they
    were to the clouds)."""

    fused: FusedCloud
    depth_views: Sequence[DepthView] = ()
    roi: RegionOfInterest = RegionOfInterest(shape="none")
    remove_points: RemovePoints | None = None
    # One Poisson solve serves both "poisson" and "poisson_closed" (they may run in parallel).
    shared: dict = field(default_factory=dict, compare=False)
    lock: threading.Lock = field(default_factory=threading.Lock, compare=False)


def _poisson_solution(inputs: SurfaceInput, config: SurfaceConfig):
    """The untrimmed Poisson surface and its densities, solved once per input."""
    with inputs.lock:
        if "poisson" not in inputs.shared:
            fused = inputs.fused
            if len(fused) < 100:
                raise ScannerError(f"Poisson: only {len(fused)} fused points, nothing to mesh")
            s = solve_poisson_apart(
                fused.points_W, fused.normals_W, fused.colors, config.poisson_depth
            )
            mesh = o3d.geometry.TriangleMesh(
                o3d.utility.Vector3dVector(s.vertices), o3d.utility.Vector3iVector(s.triangles)
            )
            if len(s.colors):
                mesh.vertex_colors = o3d.utility.Vector3dVector(s.colors)
            inputs.shared["poisson"] = (mesh, s.density)
        mesh, density = inputs.shared["poisson"]
    return o3d.geometry.TriangleMesh(mesh), density


def _unsupported(inputs: SurfaceInput, mesh, config: SurfaceConfig) -> np.ndarray:
    """Vertices farther than poisson_max_distance_m from every fused point."""
    far, _ = cKDTree(inputs.fused.points_W).query(
        np.asarray(mesh.vertices), distance_upper_bound=config.poisson_max_distance_m, workers=-1
    )
    return ~np.isfinite(far)


def poisson_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """Poisson trimmed to the data: what was seen, open where nothing was."""
    mesh, density = _poisson_solution(inputs, config)
    drop = density < np.quantile(density, config.poisson_density_quantile)
    mesh.remove_vertices_by_mask(drop | _unsupported(inputs, mesh, config))
    return finish_mesh("poisson", mesh, config)


def poisson_closed_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """Poisson untrimmed, its main component: closed where the data surround the object (a
    collision model, a print), with the area it bridges beyond the data as `filled_area_m2`."""
    mesh, _ = _poisson_solution(inputs, config)
    clusters, counts = triangle_components(np.asarray(mesh.triangles))
    mesh.remove_triangles_by_mask(clusters != int(np.argmax(counts)))
    mesh.remove_unreferenced_vertices()
    out = finish_mesh("poisson_closed", mesh, config)
    unsupported = _unsupported(inputs, mesh, config)
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    bridged = unsupported[t].all(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
    return replace(out, filled_area_m2=out.filled_area_m2 + float(area[bridged].sum()))


def ball_pivoting_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    fused = inputs.fused
    pc = o3d_cloud(fused.points_W, fused.normals_W, fused.colors)
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pc, o3d.utility.DoubleVector(list(config.ball_pivoting_radii_m))
    )
    return finish_mesh("ball_pivoting", mesh, config)


def rbf_params(config: SurfaceConfig) -> RbfParams:
    """The RBF surface's settings (`surfaces.rbf_*`)."""
    return RbfParams(
        centre_spacing_m=config.rbf_centre_spacing_m,
        max_centres=config.rbf_max_centres,
        offset_m=config.rbf_offset_m,
        kernel=config.rbf_kernel,
        neighbors=config.rbf_neighbors,
        smoothing=config.rbf_smoothing,
        voxel_size_m=config.rbf_voxel_size_m,
        max_distance_m=config.rbf_max_distance_m,
    )


def rbf_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """The RBF implicit surface of the fused cloud where the data are, coloured by the
    nearest fused point."""
    fused = inputs.fused
    surface = rbf_surface(fused.points_W, fused.normals_W, rbf_params(config))
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(surface.vertices),
        o3d.utility.Vector3iVector(surface.triangles.astype(np.int32)),
    )
    if len(surface.vertices):
        _, nearest = cKDTree(fused.points_W).query(surface.vertices)
        mesh.vertex_colors = o3d.utility.Vector3dVector(fused.colors[nearest] / 255.0)
    return finish_mesh("rbf", canonical_order(mesh), config)


def masked_depth(
    view: DepthView, roi: RegionOfInterest, remove_points: RemovePoints | None
) -> np.ndarray:
    """The depth map with pixels outside the region of interest or rejected by the caller's
    hook set to 0 (no data), so TSDF fusion sees the same points as the clouds."""
    depth = view.depth.depth_m.copy()
    v, u = np.nonzero(depth > 0)
    if not len(v):
        return depth
    K = view.depth.K
    z = depth[v, u].astype(np.float64)
    p_D = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    p_W = transform_points(view.X_WC @ view.depth.X_CD, p_D)
    keep = roi.contains(p_W)
    if remove_points is not None and keep.any():
        # The robot/cell test is the costly one: only on the points the region keeps, and once
        # per HOOK_CELL_M cell (its ~7 pixels share the decision of its first one).
        inside = np.flatnonzero(keep)
        cells = np.floor(p_W[inside] / HOOK_CELL_M).astype(np.int64)
        cells -= cells.min(axis=0)
        span = cells.max(axis=0) + 1
        key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
        _, first, cell_of = np.unique(key, return_index=True, return_inverse=True)
        kept = apply_hook(remove_points, p_W[inside[first]], view.index)
        keep[inside] = kept[cell_of]
    depth[v[~keep], u[~keep]] = 0
    return depth


def tsdf_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """Open3D tensor VoxelBlockGrid TSDF of the depth maps (the legacy ScalableTSDFVolume gave
    0 triangles with float depth in metres in a prototype); colours when the depth maps have
    them."""
    depth_views, roi, remove_points = inputs.depth_views, inputs.roi, inputs.remove_points
    if not depth_views:
        raise ScannerError("TSDF: no depth maps given (the views carry no DepthImage)")
    with_color = all(v.depth.color is not None for v in depth_views)
    names = ("tsdf", "weight", "color") if with_color else ("tsdf", "weight")
    f32 = o3d.core.float32
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=names,
        attr_dtypes=(f32,) * len(names),
        attr_channels=((1), (1), (3))[: len(names)],
        voxel_size=config.tsdf_voxel_size_m,
        block_resolution=16,
        block_count=config.tsdf_block_count,
        device=o3d.core.Device("CPU:0"),
    )
    for view in depth_views:
        depth = o3d.t.geometry.Image(
            o3d.core.Tensor(masked_depth(view, roi, remove_points).astype(np.float32))
        )
        K = o3d.core.Tensor(view.depth.K, o3d.core.float64)
        # Open3D's extrinsic maps world to camera: X_DW for the depth map's frame D.
        X_DW = o3d.core.Tensor(invert(view.X_WC @ view.depth.X_CD), o3d.core.float64)
        args = (1.0, config.tsdf_depth_max_m, config.tsdf_truncation_voxels)
        blocks = grid.compute_unique_block_coordinates(depth, K, X_DW, *args)
        if with_color:
            color = o3d.t.geometry.Image(
                o3d.core.Tensor(np.ascontiguousarray(view.depth.color, np.float32) / 255.0)
            )
            grid.integrate(blocks, depth, color, K, X_DW, *args)
        else:
            grid.integrate(blocks, depth, K, X_DW, *args)
    # Each integration adds 1 to a voxel's weight and Open3D keeps voxels above the threshold
    # (a threshold of 1.0 dropped every voxel seen once: 12 % of the observed surface).
    threshold = config.tsdf_min_views - 0.5
    mesh = canonical_order(grid.extract_triangle_mesh(weight_threshold=threshold).to_legacy())
    if len(mesh.vertices):
        mesh.remove_vertices_by_mask(~roi.contains(np.asarray(mesh.vertices)))
    return finish_mesh("tsdf", mesh, config)


SURFACE_METHODS: dict[str, Callable[[SurfaceInput, SurfaceConfig], SurfaceMesh]] = {
    "poisson": poisson_mesh,
    "poisson_closed": poisson_closed_mesh,
    "tsdf": tsdf_mesh,
    "ball_pivoting": ball_pivoting_mesh,
    "rbf": rbf_mesh,
}


def build_surface(
    method: str,
    fused: FusedCloud,
    config: SurfaceConfig,
    depth_views: Sequence[DepthView] = (),
    roi: RegionOfInterest | None = None,
    remove_points: RemovePoints | None = None,
) -> SurfaceMesh:
    if method not in SURFACE_METHODS:
        raise ScannerError(
            f"unknown surface method '{method}'; valid: {', '.join(SURFACE_METHODS)}"
        )
    inputs = SurfaceInput(fused, depth_views, roi or RegionOfInterest(shape="none"), remove_points)
    return surface_from(method, inputs, config)


def surface_from(method: str, inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """One surface from inputs that several methods may share (one Poisson solve)."""
    if method not in SURFACE_METHODS:
        raise ScannerError(
            f"unknown surface method '{method}'; valid: {', '.join(SURFACE_METHODS)}"
        )
    return SURFACE_METHODS[method](inputs, config)


def save_mesh(mesh: SurfaceMesh, path: Path) -> None:
    """PLY, OBJ or STL by suffix, metres in W."""
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ScannerError(f"{path}: mesh output must be one of {', '.join(MESH_SUFFIXES)}")
    m = mesh.to_open3d()
    m.compute_triangle_normals()
    m.compute_vertex_normals()
    if path.suffix.lower() == ".stl":
        m.vertex_colors = o3d.utility.Vector3dVector()
    if not o3d.io.write_triangle_mesh(str(path), m, write_ascii=False):
        raise ScannerError(f"{path}: could not write the mesh")


def save_cloud(fused: FusedCloud, path: Path) -> None:
    """PLY with normals and colours, metres in W."""
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise ScannerError(f"{path}: the fused cloud is written as .ply")
    cloud = o3d_cloud(fused.points_W, fused.normals_W, fused.colors)
    if not o3d.io.write_point_cloud(str(path), cloud):
        raise ScannerError(f"{path}: could not write the cloud")

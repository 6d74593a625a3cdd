"""What the surfaces are built with (the `surfaces:` section of the processing configuration)."""

from __future__ import annotations

from dataclasses import dataclass

from reconstruction.common.checks import (
    check_fields,
    integer,
    non_negative,
    positive,
    require_choice,
)
from reconstruction.common.errors import ScannerError
from reconstruction.surfaces.rbf import RBF_KERNELS

# What `methods` may name; reconstruction.surfaces.build.SURFACE_METHODS implements each.
SURFACE_METHOD_NAMES = ("poisson", "poisson_closed", "tsdf", "ball_pivoting", "rbf")


@dataclass(frozen=True)
class SurfaceConfig:
    # Poisson alone by default: it is the headline (the most accurate on every benchmark
    # object) and TSDF beside it cost ~4 s of CPU after the last picture that nobody read;
    # "tsdf", "rbf", "ball_pivoting" and "poisson_closed" stay available on request.
    methods: tuple[str, ...] = ("poisson",)
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
    # Cheaper solves measured on the vase's fused clouds (scripts/bench_poisson.py; solve CPU s
    # / observed Chamfer mm, 24 views | 48 views | two hangings): Open3D as here 5.0 / 0.138 |
    # 5.2 / 0.143 | 7.1 / 0.085; the cloud first averaged over 1.5 octree cells 4.3 / 0.142 |
    # 4.7 / 0.152 | 6.7 / 0.087, over 2 cells (in effect depth 7) 1.9 / 0.143 | 1.8 / 0.159 |
    # 2.3 / 0.100; PoissonRecon itself through pymeshlab, one thread (its output repeats)
    # 11.0 / 0.138 (24 views), two threads 54 CPU s on a loaded machine and another mesh each
    # run. The depth whose cells match the 1 mm voxel on these ~0.2 m objects is this 8.
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
        unknown = [m for m in self.methods if m not in SURFACE_METHOD_NAMES]
        if unknown:
            raise ScannerError(
                f"surfaces.methods: unknown {', '.join(unknown)}; valid: "
                f"{', '.join(SURFACE_METHOD_NAMES)}"
            )
        check_fields("surfaces", self)
        require_choice("surfaces", "rbf_kernel", self.rbf_kernel, RBF_KERNELS)
        for name in ("poisson_density_quantile", "min_component_fraction"):
            value = getattr(self, name)
            if not 0 <= value < 1:
                raise ScannerError(f"surfaces.{name}: expected a number in [0, 1), got {value!r}")
        if not 4 <= self.poisson_depth <= 12:
            raise ScannerError("surfaces.poisson_depth: between 4 and 12")
        if not self.ball_pivoting_radii_m or min(self.ball_pivoting_radii_m) <= 0:
            raise ScannerError("surfaces.ball_pivoting_radii_m: positive radii")

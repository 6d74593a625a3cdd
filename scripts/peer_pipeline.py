"""The peer pipeline of bench_peer.py: Open3D's reconstruction system tutorial
(`examples/python/reconstruction_system`: make_fragments, register_fragments,
refine_registration, integrate_scene) adapted to an eye-in-hand scan's views.

What is kept from the tutorial, and what had to change for these captures:
- Fragments: each view is one fragment. The tutorial builds fragments from RGB-D odometry over
  100-frame runs of a hand-held sensor; here every view is a separate robot pose, and its cloud
  is the product's filtered cloud of that view (stereo, region of interest, 1 mm voxels,
  outliers, robot and cell points removed), so both pipelines start from the same points.
- register_fragments: every pair (s, t) is considered. Its global registration (RANSAC on FPFH
  features) is replaced by the robot's poses at the nominal hand-eye transform as the initial
  X_TS; the tutorial's acceptance test stays: a non-adjacent pair is kept only when the
  correspondences at `voxel_size * 1.4` (information[5, 5]) cover at least 30 % of the smaller
  cloud. Adjacent pairs (t = s + 1, the capture order) are the tutorial's odometry edges
  (certain), every other kept pair a loop closure (uncertain).
- refine_registration: multiscale point-to-plane ICP (`registration_icp`) at voxel sizes
  [v, v/2, v/4] with [50, 30, 14] iterations, the correspondence distance `v * 1.4` at every
  scale, normals re-estimated per scale (radius 2 x that scale, 30 neighbours), and the
  information matrix from `get_information_matrix_from_point_clouds` on the finest scale.
- Global optimisation: `global_optimization` with Levenberg-Marquardt, the tutorial's scene
  options (max_correspondence_distance `v * 1.4`, edge_prune_threshold 0.25,
  preference_loop_closure 5.0, reference_node 0), run once on the refined graph (the tutorial
  also optimises the unrefined graph first; with robot poses as the start there is nothing for
  that pass to fix).
- integrate_scene: TSDF fusion of the views' depth maps at the optimised poses, voxel
  `tsdf_cubic_size / 512`, truncation 0.04 m, then `extract_triangle_mesh`. The tutorial's
  `ScalableTSDFVolume` returns no voxel at all in the installed Open3D (0.20: not even for one
  flat depth map, whatever the depth type, stride or voxel size), so its successor in Open3D,
  the tensor `VoxelBlockGrid` (the same hashed-block TSDF, Open3D's tensor reconstruction
  tutorial), runs with the same voxel, truncation and depth limit, and meshes every voxel seen
  at least once (the legacy volume's rule). The depth maps are the product's, masked as the
  product masks them for its own TSDF (region of interest, robot and cell).
- Lengths: the tutorial is set for rooms; every length of it that follows the scene's size
  (voxel_size 0.05 m, tsdf_cubic_size 3.0 m, sdf_trunc 0.04 m) is scaled by the object's size
  over the tutorial's 3.0 m cube (`tutorial_scaled`). Its max_depth (3.0 m) is a sensor range,
  not a scene size, and stays: the depth maps hold only the object's depth window anyway.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from reconstruction.common.stage_timer import StageTimer
from reconstruction.common.transforms import invert
from reconstruction.registration.filtering import RegionOfInterest, RemovePoints
from reconstruction.registration.views import DepthImage
from reconstruction.surfaces.meshes import DepthView
from reconstruction.surfaces.tsdf import masked_depth

reg = o3d.pipelines.registration

# The tutorial's config.json defaults that are lengths in a room-sized scene.
TUTORIAL_CUBE_M = 3.0  # tsdf_cubic_size
TUTORIAL_VOXEL_M = 0.05  # voxel_size (registration)
TUTORIAL_SDF_TRUNC_M = 0.04  # integrate_scene's sdf_trunc


@dataclass(frozen=True)
class PeerConfig:
    """The tutorial's settings; lengths in metres."""

    voxel_size_m: float  # the tutorial's voxel_size: registration's coarsest scale
    tsdf_voxel_size_m: float  # tsdf_cubic_size / 512
    sdf_trunc_m: float
    max_depth_m: float = 3.0
    icp_iterations: tuple[int, ...] = (50, 30, 14)
    # register_fragments: a loop closure needs this share of the smaller cloud matched.
    min_overlap: float = 0.3
    edge_prune_threshold: float = 0.25
    preference_loop_closure: float = 5.0  # preference_loop_closure_registration
    normal_max_nn: int = 30

    @property
    def max_correspondence_m(self) -> float:
        return 1.4 * self.voxel_size_m


def tutorial_scaled(object_size_m: float) -> PeerConfig:
    """The tutorial's lengths scaled from its 3.0 m scene cube to an object whose largest
    extent is `object_size_m` (its cube)."""
    s = object_size_m / TUTORIAL_CUBE_M
    return PeerConfig(
        voxel_size_m=TUTORIAL_VOXEL_M * s,
        tsdf_voxel_size_m=TUTORIAL_CUBE_M * s / 512.0,
        sdf_trunc_m=TUTORIAL_SDF_TRUNC_M * s,
    )


@dataclass(frozen=True, eq=False)
class PeerView:
    """One view for the peer: its cloud (N, 3) in the camera frame C, the start pose X_WC (the
    robot's flange pose at the nominal X_FC), its depth map (intrinsics, frame, colour) and
    that map's depths (H, W) m masked as the product masks them (0: no data)."""

    index: int
    points_C: np.ndarray
    X_WC_start: np.ndarray
    depth: DepthImage
    depth_m: np.ndarray


@dataclass(frozen=True, eq=False)
class PeerEdge:
    source: int  # positions in the view list
    target: int
    X_TS: np.ndarray  # source camera in the target camera
    information: np.ndarray  # (6, 6)
    uncertain: bool
    fitness: float


@dataclass(frozen=True, eq=False)
class PeerResult:
    X_WC: list[np.ndarray]  # the optimised camera poses, in view order
    vertices: np.ndarray  # (V, 3) m in W
    triangles: np.ndarray  # (M, 3)
    edges: list[PeerEdge]
    edges_kept: int  # after the optimisation's pruning
    pairs_tried: int
    stage_s: dict[str, float]  # wall seconds of pairs, pose_graph and tsdf


def _cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(points, np.float64)))


def _down(cloud: o3d.geometry.PointCloud, voxel_m: float, max_nn: int):
    """The tutorial's preprocessing: voxel grid, then normals over twice the voxel."""
    down = cloud.voxel_down_sample(voxel_m)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.0 * voxel_m, max_nn=max_nn))
    return down


def overlap(source, target, X_TS: np.ndarray, config: PeerConfig) -> float:
    """register_fragments' test: matched correspondences (information[5, 5]) over the smaller
    cloud's points, both at the tutorial's voxel size."""
    information = reg.get_information_matrix_from_point_clouds(
        source, target, config.max_correspondence_m, X_TS
    )
    return float(information[5, 5]) / max(min(len(source.points), len(target.points)), 1)


def pyramid(points_C: np.ndarray, config: PeerConfig) -> list[o3d.geometry.PointCloud]:
    """One cloud at each of refine_registration's scales [v, v/2, v/4, ...], with normals.
    The tutorial redoes this for both clouds of every pair; made once per view here, the same
    clouds (both steps are deterministic) at a 23rd of the cost for 24 views."""
    cloud = _cloud(points_C)
    return [
        _down(cloud, config.voxel_size_m / 2.0**level, config.normal_max_nn)
        for level in range(len(config.icp_iterations))
    ]


def multiscale_icp(source: list, target: list, X_TS_init: np.ndarray, config: PeerConfig):
    """refine_registration's multiscale_icp, point to plane, on two `pyramid`s:
    (X_TS, information, fitness)."""
    X_TS = np.asarray(X_TS_init, float)
    for level, iterations in enumerate(config.icp_iterations):
        result = reg.registration_icp(
            source[level],
            target[level],
            config.max_correspondence_m,
            X_TS,
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(max_iteration=iterations),
        )
        X_TS = np.asarray(result.transformation)
    finest = config.voxel_size_m / 2.0 ** (len(config.icp_iterations) - 1)
    information = reg.get_information_matrix_from_point_clouds(
        source[-1], target[-1], 1.4 * finest, X_TS
    )
    return X_TS, np.asarray(information), float(result.fitness)


def register_pairs(views: Sequence[PeerView], config: PeerConfig) -> tuple[list[PeerEdge], int]:
    """Every pair that passes the tutorial's overlap test at the start poses (adjacent pairs
    always), refined by multiscale ICP; and the number of pairs tried."""
    clouds = [pyramid(v.points_C, config) for v in views]
    coarse = [c[0] for c in clouds]
    edges, tried = [], 0
    for s in range(len(views)):
        for t in range(s + 1, len(views)):
            tried += 1
            X_TS = invert(views[t].X_WC_start) @ views[s].X_WC_start
            adjacent = t == s + 1
            if not adjacent and overlap(coarse[s], coarse[t], X_TS, config) < config.min_overlap:
                continue
            X_TS, information, fitness = multiscale_icp(clouds[s], clouds[t], X_TS, config)
            edges.append(PeerEdge(s, t, X_TS, information, not adjacent, fitness))
    return edges, tried


def optimise_poses(
    X_WC_start: Sequence[np.ndarray], edges: Sequence[PeerEdge], config: PeerConfig
) -> tuple[list[np.ndarray], int]:
    """Open3D's pose graph (node pose = X_WC; an edge's transformation = X_TS) optimised with
    Levenberg-Marquardt and the tutorial's scene options; the poses and the edges it kept."""
    graph = reg.PoseGraph()
    for X_WC in X_WC_start:
        graph.nodes.append(reg.PoseGraphNode(np.asarray(X_WC, float)))
    for e in edges:
        graph.edges.append(
            reg.PoseGraphEdge(e.source, e.target, e.X_TS, e.information, uncertain=e.uncertain)
        )
    option = reg.GlobalOptimizationOption(
        max_correspondence_distance=config.max_correspondence_m,
        edge_prune_threshold=config.edge_prune_threshold,
        preference_loop_closure=config.preference_loop_closure,
        reference_node=0,
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(
            graph,
            reg.GlobalOptimizationLevenbergMarquardt(),
            reg.GlobalOptimizationConvergenceCriteria(),
            option,
        )
    return [np.asarray(n.pose).copy() for n in graph.nodes], len(graph.edges)


def integrate(
    views: Sequence[PeerView], X_WC: Sequence[np.ndarray], config: PeerConfig
) -> o3d.geometry.TriangleMesh:
    """integrate_scene: the depth maps (colour when every one has it) at the given poses."""
    with_color = all(v.depth.color is not None for v in views)
    names = ("tsdf", "weight", "color") if with_color else ("tsdf", "weight")
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=names,
        attr_dtypes=(o3d.core.float32,) * len(names),
        attr_channels=((1), (1), (3))[: len(names)],
        voxel_size=config.tsdf_voxel_size_m,
        block_resolution=16,
        block_count=50_000,
        device=o3d.core.Device("CPU:0"),
    )
    trunc_voxels = config.sdf_trunc_m / config.tsdf_voxel_size_m
    for view, X in zip(views, X_WC, strict=True):
        image = view.depth
        depth = o3d.t.geometry.Image(
            o3d.core.Tensor(np.ascontiguousarray(view.depth_m, np.float32))
        )
        K = o3d.core.Tensor(image.K, o3d.core.float64)
        # Open3D's extrinsic maps world to camera: X_DW for the depth map's frame D.
        X_DW = o3d.core.Tensor(invert(X @ image.X_CD), o3d.core.float64)
        args = (1.0, config.max_depth_m, trunc_voxels)
        blocks = grid.compute_unique_block_coordinates(depth, K, X_DW, *args)
        if with_color:
            color = o3d.t.geometry.Image(
                o3d.core.Tensor(np.ascontiguousarray(image.color, np.float32) / 255.0)
            )
            grid.integrate(blocks, depth, color, K, X_DW, *args)
        else:
            grid.integrate(blocks, depth, K, X_DW, *args)
    # Weights count integrations: 0.5 keeps every voxel seen once, as the legacy volume does.
    return grid.extract_triangle_mesh(weight_threshold=0.5).to_legacy()


def peer_reconstruct(views: Sequence[PeerView], config: PeerConfig) -> PeerResult:
    """The whole peer pipeline on prepared views: pairs, pose graph, TSDF mesh."""
    timer = StageTimer()
    with timer("pairs"):
        edges, tried = register_pairs(views, config)
    with timer("pose_graph"):
        X_WC, kept = optimise_poses([v.X_WC_start for v in views], edges, config)
    with timer("tsdf"):
        mesh = integrate(views, X_WC, config)
    return PeerResult(
        X_WC,
        np.asarray(mesh.vertices).copy(),
        np.asarray(mesh.triangles).copy(),
        edges,
        kept,
        tried,
        dict(timer.seconds),
    )


def peer_views(
    views, clouds, X_FC: np.ndarray, roi: RegionOfInterest, remove: RemovePoints | None
) -> list[PeerView]:
    """The peer's input from the product's per-view data: `views` (ViewCloud, with depth maps)
    and their filtered `clouds` (FilteredCloud, same order), at the nominal X_FC."""
    out = []
    for view, cloud in zip(views, clouds, strict=True):
        X_WC = view.X_WF @ X_FC
        depth_m = masked_depth(DepthView(view.depth, X_WC, view.index), roi, remove)
        out.append(PeerView(view.index, cloud.points_C, X_WC, view.depth, depth_m))
    return out


def pose_change(X_a: np.ndarray, X_b: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation rad) between two poses."""
    d = invert(X_a) @ X_b
    cos = np.clip((np.trace(d[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(d[:3, 3])), float(math.acos(cos))

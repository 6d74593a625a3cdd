"""TSDF fusion of the views' depth maps at their poses (Open3D's VoxelBlockGrid), with the
region of interest and the robot/cell point filter applied to the depth maps as to the clouds."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.registration.filtering import (
    RegionOfInterest,
    RemovePoints,
    apply_hook,
)
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.meshes import DepthView, SurfaceInput, SurfaceMesh, finish_mesh
from reconstruction.surfaces.topology import (
    canonical_order,
)

# The depth maps' robot/cell removal decides per cell of this size, not per pixel: the pixels
# of a 1 mm cell (~7 at 0.5 m) are one fused voxel anyway, and the removal margin is 10 mm.
# On the 24-view bunny the removal took 2.8 of the TSDF's 6.4 s per pixel.
HOOK_CELL_M = 0.001


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


BLOCK_RESOLUTION = 16  # voxels along a block's edge (Open3D's usual)


def _grid(names: tuple[str, ...], config: SurfaceConfig, blocks: int):
    f32 = o3d.core.float32
    return o3d.t.geometry.VoxelBlockGrid(
        attr_names=names,
        attr_dtypes=(f32,) * len(names),
        attr_channels=((1), (1), (3))[: len(names)],
        voxel_size=config.tsdf_voxel_size_m,
        block_resolution=BLOCK_RESOLUTION,
        block_count=blocks,
        device=o3d.core.Device("CPU:0"),
    )


def tsdf_mesh(inputs: SurfaceInput, config: SurfaceConfig) -> SurfaceMesh:
    """Open3D tensor VoxelBlockGrid TSDF of the depth maps (the legacy ScalableTSDFVolume gave
    0 triangles with float depth in metres in a prototype); colours when the depth maps have
    them."""
    depth_views, roi, remove_points = inputs.depth_views, inputs.roi, inputs.remove_points
    if not depth_views:
        raise ScannerError("TSDF: no depth maps given (the views carry no DepthImage)")
    with_color = all(v.depth.color is not None for v in depth_views)
    names = ("tsdf", "weight", "color") if with_color else ("tsdf", "weight")
    args = (1.0, config.tsdf_depth_max_m, config.tsdf_truncation_voxels)

    def frame(view: DepthView):
        depth = o3d.t.geometry.Image(
            o3d.core.Tensor(masked_depth(view, roi, remove_points).astype(np.float32))
        )
        K = o3d.core.Tensor(view.depth.K, o3d.core.float64)
        # Open3D's extrinsic maps world to camera: X_DW for the depth map's frame D.
        X_DW = o3d.core.Tensor(invert(view.X_WC @ view.depth.X_CD), o3d.core.float64)
        return depth, K, X_DW

    # The grid holds exactly the blocks the views touch. Allocated up front for a fixed 40,000
    # blocks it cost 3.3 GB of address space and 1.8 s of zero-filling per surface (with
    # colour), whatever the object; left to grow, it rehashes as it goes. The blocks come from
    # a scratch grid (they depend on the depth map and the pose alone); the masked depth maps
    # are kept for the integration (the robot/cell mask is the costly part of a view).
    frames = [frame(view) for view in depth_views]
    scratch = _grid(names[:2], config, 1)
    blocks = [scratch.compute_unique_block_coordinates(*f, *args) for f in frames]
    touched = np.unique(np.concatenate([b.numpy() for b in blocks]), axis=0)
    grid = _grid(names, config, max(len(touched), 1))
    for view, (depth, K, X_DW), view_blocks in zip(depth_views, frames, blocks, strict=True):
        if with_color:
            color = o3d.t.geometry.Image(
                o3d.core.Tensor(np.ascontiguousarray(view.depth.color, np.float32) / 255.0)
            )
            grid.integrate(view_blocks, depth, color, K, X_DW, *args)
        else:
            grid.integrate(view_blocks, depth, K, X_DW, *args)
    # Each integration adds 1 to a voxel's weight and Open3D keeps voxels above the threshold
    # (a threshold of 1.0 dropped every voxel seen once: 12 % of the observed surface).
    threshold = config.tsdf_min_views - 0.5
    mesh = canonical_order(grid.extract_triangle_mesh(weight_threshold=threshold).to_legacy())
    if len(mesh.vertices):
        mesh.remove_vertices_by_mask(~roi.contains(np.asarray(mesh.vertices)))
    return finish_mesh("tsdf", mesh, config)

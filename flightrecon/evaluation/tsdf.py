"""TSDF fusion of depth maps into a triangle mesh (the paper's mesh extraction, Section V-B).

Why Open3D: its TSDF volume is the field's standard for this step (2DGS's own mesh extraction
fuses rendered depth with it), so our mesh numbers come from the same fusion as published ones.
We use the tensor API's `open3d.t.geometry.VoxelBlockGrid` (Curless and Levoy 1996 projective TSDF
on a hashed grid of 16^3-voxel blocks, allocated where the depth is, so the volume follows the
observed scene and not a fixed room size; Open3D's marching cubes extracts the zero level set, and
voxels never observed have weight 0 and yield no surface). The legacy `ScalableTSDFVolume` is not
used: in open3d 0.20 it places its blocks by `PointCloud.create_from_depth_image(depth,
depth_scale=1000)`, which divides the float depth image (already in meters) by 1000 again, so the
blocks land at the camera and metric depth fuses to nothing (seen here: a plane at 1 m gave an empty
mesh).

What it is given: each z-depth map in meters (0 = invalid) as a float32 image with depth_scale=1
and depth_max=max_depth (farther depth is dropped), optionally an RGB image in [0, 1] per map (then a
`color` voxel attribute beside `tsdf` and `weight`, averaged like the distance, and the mesh has
vertex colours; the evaluation fuses depth only, scan-like test scenes fuse colour too),
voxel_size=voxel, sdf truncation = truncation (as `trunc_voxel_multiplier` = truncation / voxel),
intrinsics K as is and extrinsic = world-to-camera = inverse(T_wc). Our cameras are OpenCV's (x
right, y down, z forward), as are Open3D's, and so is the pixel convention of its tensor integration
(a point projecting to u in [i, i+1) reads pixel i, whose center is i + 0.5), so K needs no
half-pixel shift. Every voxel observed once counts (weight_threshold=0); the signed
distance is along the optical axis, d - z, clamped to the truncation, averaged with weight 1 per view.

Open3D is imported on the first fusion (`open3d_import`), not with this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flightrecon.geometry import backproject_depth, invert_pose
from flightrecon.open3d_import import open3d_module


@dataclass
class TriangleMesh:
    vertices: np.ndarray  # (V,3) float64, world meters
    faces: np.ndarray  # (F,3) int64
    vertex_colors: np.ndarray | None = None  # (V,3) float64 in [0, 1], when colours were fused


def fuse_depth_maps(depths: list[np.ndarray], poses: np.ndarray, K: np.ndarray, *, voxel: float,
                    truncation: float, max_depth: float = 10.0,
                    colors: list[np.ndarray] | None = None) -> TriangleMesh:
    """Mesh of the zero crossing of Open3D's TSDF fused from z-depth maps (0 = invalid) at T_wc poses;
    with `colors` (one (H, W, 3) RGB image in [0, 1] per map), its vertices carry the fused colour."""
    o3d = open3d_module()
    o3c = o3d.core
    names, channels = ("tsdf", "weight") + (("color",) if colors is not None else ()), ((1,), (1,), (3,))
    grid = o3d.t.geometry.VoxelBlockGrid(attr_names=names, attr_dtypes=(o3c.float32,) * len(names),
                                         attr_channels=channels[:len(names)], voxel_size=float(voxel),
                                         block_resolution=16,
                                         block_count=1000)  # the CPU hash map grows as blocks are added
    intrinsic = o3c.Tensor(np.asarray(K, np.float64))
    multiplier = float(truncation) / float(voxel)
    for k, (depth, T_wc) in enumerate(zip(depths, poses)):
        d = np.asarray(depth, np.float32)
        valid = np.isfinite(d) & (d > 0) & (d <= max_depth)
        if not valid.any():  # Open3D refuses a frame that touches no block
            continue
        d = np.where(valid, d, 0.0).astype(np.float32)
        # blocks within the truncation of every valid pixel's point (Open3D's own depth overload samples
        # every 4th pixel only, and misses surfaces seen by fewer pixels)
        points = o3d.t.geometry.PointCloud(o3c.Tensor(backproject_depth(d, K, T_wc)[0].astype(np.float32)))
        blocks = grid.compute_unique_block_coordinates(points, trunc_voxel_multiplier=multiplier)
        extrinsic = o3c.Tensor(invert_pose(np.asarray(T_wc, np.float64)))
        image = o3d.t.geometry.Image(o3c.Tensor(d))
        if colors is None:
            grid.integrate(blocks, image, intrinsic, extrinsic, depth_scale=1.0, depth_max=float(max_depth),
                           trunc_voxel_multiplier=multiplier)
        else:
            rgb = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(colors[k], np.float32)))
            grid.integrate(blocks, image, rgb, intrinsic, intrinsic, extrinsic, depth_scale=1.0,
                           depth_max=float(max_depth), trunc_voxel_multiplier=multiplier)
    if grid.hashmap().size() == 0:
        return TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64),
                            None if colors is None else np.zeros((0, 3)))
    mesh = grid.extract_triangle_mesh(weight_threshold=0.0)
    vertex_colors = None if colors is None else mesh.vertex.colors.numpy().astype(np.float64).reshape(-1, 3)
    return TriangleMesh(mesh.vertex.positions.numpy().astype(np.float64).reshape(-1, 3),
                        mesh.triangle.indices.numpy().astype(np.int64).reshape(-1, 3), vertex_colors)

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
and depth_max=max_depth (farther depth is dropped), no colour (only `tsdf` and `weight` voxel
attributes), voxel_size=voxel, sdf truncation = truncation (as `trunc_voxel_multiplier` =
truncation / voxel), intrinsics K as is and extrinsic = world-to-camera = inverse(T_wc). Our cameras
are OpenCV's (x right, y down, z forward), as are Open3D's, and so is the pixel convention of its
tensor integration (a point projecting to u in [i, i+1) reads pixel i, whose center is i + 0.5), so
K needs no half-pixel shift. Every voxel observed once counts (weight_threshold=0); the signed
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


def fuse_depth_maps(depths: list[np.ndarray], poses: np.ndarray, K: np.ndarray, *, voxel: float,
                    truncation: float, max_depth: float = 10.0) -> TriangleMesh:
    """Mesh of the zero crossing of Open3D's TSDF fused from z-depth maps (0 = invalid) at T_wc poses."""
    o3d = open3d_module()
    o3c = o3d.core
    grid = o3d.t.geometry.VoxelBlockGrid(attr_names=("tsdf", "weight"), attr_dtypes=(o3c.float32, o3c.float32),
                                         attr_channels=((1,), (1,)), voxel_size=float(voxel), block_resolution=16,
                                         block_count=1000)  # the CPU hash map grows as blocks are added
    intrinsic = o3c.Tensor(np.asarray(K, np.float64))
    multiplier = float(truncation) / float(voxel)
    for depth, T_wc in zip(depths, poses):
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
        grid.integrate(blocks, o3d.t.geometry.Image(o3c.Tensor(d)), intrinsic, extrinsic, depth_scale=1.0,
                       depth_max=float(max_depth), trunc_voxel_multiplier=multiplier)
    if grid.hashmap().size() == 0:
        return TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    mesh = grid.extract_triangle_mesh(weight_threshold=0.0)
    return TriangleMesh(mesh.vertex.positions.numpy().astype(np.float64).reshape(-1, 3),
                        mesh.triangle.indices.numpy().astype(np.int64).reshape(-1, 3))

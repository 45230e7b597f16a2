"""TSDF fusion of depth maps into a triangle mesh (the paper's mesh extraction, Section V-B).

Why our own: Open3D's ScalableTSDFVolume is the usual tool, but its wheel does not import on our
platform (it needs the system libusb-1.0), so this is a small vectorized numpy implementation of
the same projective TSDF (Curless and Levoy 1996): every voxel center is projected into each depth
map; where the measured depth d is valid and the signed distance along the optical axis
sdf = d - z exceeds -truncation, the voxel takes tsdf = min(1, sdf / truncation) into a running
weighted mean (weight 1 per view). The zero level set is extracted with scikit-image's
`measure.marching_cubes` on voxels that were observed (weight > 0); voxels never observed keep
tsdf = 1 and are masked out, so unknown space yields no surface.

The volume covers the axis-aligned box of the back-projected depth points (plus the truncation),
so its size follows the observed scene and not a fixed room size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from skimage import measure

from flightrecon.geometry import backproject_depth, project_points


@dataclass
class TriangleMesh:
    vertices: np.ndarray  # (V,3) float64, world meters
    faces: np.ndarray  # (F,3) int64


def fuse_depth_maps(depths: list[np.ndarray], poses: np.ndarray, K: np.ndarray, *, voxel: float,
                    truncation: float, max_depth: float = 10.0, chunk: int = 1 << 21) -> TriangleMesh:
    """Mesh of the zero crossing of the TSDF fused from z-depth maps (0 = invalid) at T_wc poses."""
    depths = [np.where(np.asarray(d, float) <= max_depth, np.asarray(d, float), 0.0) for d in depths]
    pts = [backproject_depth(d, K, T)[0] for d, T in zip(depths, poses)]
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(pts) == 0:
        return TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    lo = pts.min(0) - truncation - voxel
    dims = np.ceil((pts.max(0) + truncation + voxel - lo) / voxel).astype(int) + 1
    n = int(np.prod(dims))
    tsdf = np.ones(n, np.float32)
    weight = np.zeros(n, np.float32)
    for start in range(0, n, chunk):  # chunks of voxels bound the memory
        idx = np.arange(start, min(n, start + chunk))
        centers = lo + voxel * np.stack(np.unravel_index(idx, dims), 1)
        for depth, T in zip(depths, poses):
            H, W = depth.shape
            uv, z = project_points(centers, K, T)
            with np.errstate(invalid="ignore"):
                u, v = np.floor(uv[:, 0]), np.floor(uv[:, 1])
                inside = (z > 1e-6) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
            meas = np.zeros(len(idx))
            meas[inside] = depth[v[inside].astype(int), u[inside].astype(int)]
            sdf = meas - z
            ok = inside & (meas > 0) & (sdf > -truncation)
            if not ok.any():
                continue
            j = idx[ok]
            val = np.minimum(sdf[ok] / truncation, 1.0)
            tsdf[j] = (tsdf[j] * weight[j] + val) / (weight[j] + 1.0)
            weight[j] += 1.0
    return _marching_cubes(tsdf.reshape(dims), weight.reshape(dims) > 0, lo, voxel)


def _marching_cubes(tsdf: np.ndarray, observed: np.ndarray, origin: np.ndarray, voxel: float) -> TriangleMesh:
    empty = TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    if tsdf.min() > 0 or tsdf.max() < 0 or min(tsdf.shape) < 2:
        return empty
    try:
        verts, faces, _, _ = measure.marching_cubes(tsdf, level=0.0, spacing=(voxel,) * 3)
    except (ValueError, RuntimeError):  # no crossing
        return empty
    # keep a vertex only when both grid points of its cube edge were observed within the truncation
    # band: crossings against unknown space (tsdf 1, weight 0) are not surfaces
    good = observed & (np.abs(tsdf) < 1.0)
    g = verts / voxel
    lo = np.clip(np.floor(g + 1e-6).astype(int), 0, np.array(tsdf.shape) - 1)
    hi = np.clip(np.ceil(g - 1e-6).astype(int), 0, np.array(tsdf.shape) - 1)
    ok_v = good[tuple(lo.T)] & good[tuple(hi.T)] & np.isfinite(verts).all(1)
    faces = faces[ok_v[faces].all(1)]
    used = np.unique(faces)
    remap = np.full(len(verts), -1)
    remap[used] = np.arange(len(used))
    return TriangleMesh(verts[used].astype(np.float64) + origin, remap[faces].astype(np.int64))

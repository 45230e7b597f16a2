"""Collision boxes that follow a scene's real surfaces (MuJoCo mesh geoms collide as convex hulls).

The surface is voxelized (every triangle sampled finer than the voxel), then occupied voxels are
merged into axis-aligned boxes: runs along x, runs of equal runs along y, then along z. A wall or
floor becomes one box, furniture a few dozen; boxes reach at most 1.25 voxels beyond the surface.
Boxes are padded by the sample spacing, so every surface point is inside one.
The box count is bounded (coarser voxels) so that physics steps stay fast on sloped scans.
"""

from __future__ import annotations

import math

import numpy as np

from flightrecon.scene.types import Scene


SAMPLE_SPACING = 0.25  # surface samples per voxel edge: every surface point is this close (x pitch)


def surface_voxels(scene: Scene, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Boolean occupancy grid (X, Y, Z) of voxels holding surface samples, and its origin corner.

    Samples form a barycentric grid on every triangle with spacing <= SAMPLE_SPACING * pitch, so
    each surface point lies within that distance of an occupied voxel."""
    v = np.asarray(scene.vertices, np.float64)
    f = np.asarray(scene.faces, np.int64)
    origin = v.min(axis=0) - pitch
    dims = np.ceil((v.max(axis=0) + pitch - origin) / pitch).astype(np.int64) + 1
    occ = np.zeros(dims, bool)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    longest = np.max(np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                               np.linalg.norm(a - c, axis=1)]), axis=0)
    steps = np.maximum(1, np.ceil(longest / (SAMPLE_SPACING * pitch))).astype(np.int64)
    for n in np.unique(steps):
        sel = steps == n
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        wb, wc = (i[keep] / n), (j[keep] / n)  # barycentric grid over the triangle, corners included
        A, B, C = a[sel], b[sel], c[sel]
        for start in range(0, len(A), max(1, 2_000_000 // len(wb))):
            sl = slice(start, start + max(1, 2_000_000 // len(wb)))
            pts = A[sl, None] + (B[sl, None] - A[sl, None]) * wb[None, :, None] \
                + (C[sl, None] - A[sl, None]) * wc[None, :, None]
            idx = np.floor((pts.reshape(-1, 3) - origin) / pitch).astype(np.int64)
            occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    return occ, origin


def merge_boxes(occ: np.ndarray) -> np.ndarray:
    """Cover the occupied voxels exactly with boxes; rows of (x0, y0, z0, x1, y1, z1) voxel bounds."""
    X, Y, Z = occ.shape
    # runs along x for every (y, z) line
    pad = np.zeros((X + 2, Y, Z), np.int8)
    pad[1:-1] = occ
    d = np.diff(pad, axis=0)
    sx, sy, sz = np.nonzero(d == 1)
    ex, ey, ez = np.nonzero(d == -1)
    o1 = np.lexsort((sx, sy, sz))
    o2 = np.lexsort((ex, ey, ez))
    runs = np.stack([sx[o1], ex[o2], sy[o1], sz[o1]], axis=1)  # x0, x1 (exclusive), y, z
    # merge runs with equal (x0, x1, z) on consecutive y
    rects = _merge_consecutive(runs[:, [0, 1, 3]], runs[:, 2])  # key cols + (lo, hi) along y
    # rects: x0, x1, z, y0, y1 -> merge equal (x0, x1, y0, y1) on consecutive z
    boxes = _merge_consecutive(rects[:, [0, 1, 3, 4]], rects[:, 2])  # x0, x1, y0, y1, z0, z1
    x0, x1, y0, y1, z0, z1 = boxes.T
    return np.stack([x0, y0, z0, x1, y1, z1], axis=1)


def _merge_consecutive(keys: np.ndarray, coord: np.ndarray) -> np.ndarray:
    """Group rows with equal keys whose coord values are consecutive integers: keys + (lo, hi+1)."""
    order = np.lexsort((coord,) + tuple(keys.T[::-1]))
    k, c = keys[order], coord[order]
    new = np.ones(len(c), bool)
    new[1:] = np.any(k[1:] != k[:-1], axis=1) | (c[1:] != c[:-1] + 1)
    starts = np.nonzero(new)[0]
    ends = np.append(starts[1:], len(c)) - 1
    return np.column_stack([k[starts], c[starts], c[ends] + 1])


MAX_BOXES = 5000  # MuJoCo updates every geom each physics step: ~0.05 ms per 1000 boxes


def collision_boxes(scene: Scene, pitch: float = 0.05, max_boxes: int = MAX_BOXES) -> tuple[np.ndarray, float]:
    """World-frame boxes (N, 6): center xyz, half sizes xyz, covering the surface; and the pitch used.

    Sloped or curved surfaces of a scan merge poorly into axis-aligned boxes; while there are more
    than `max_boxes`, the voxel size doubles (coarser, still covering the surface)."""
    if not (math.isfinite(pitch) and pitch > 0):
        raise ValueError(f"collision voxel pitch must be positive, got {pitch}")
    while True:
        occ, origin = surface_voxels(scene, pitch)
        b = merge_boxes(occ).astype(np.float64)
        if len(b) <= max_boxes or max(occ.shape) <= 4:
            break
        pitch *= 2.0
    pad = SAMPLE_SPACING * pitch  # surface between samples may leave the sampled voxels by this much
    lo = origin + b[:, :3] * pitch - pad
    hi = origin + b[:, 3:] * pitch + pad
    return np.hstack([(lo + hi) / 2, (hi - lo) / 2]), pitch

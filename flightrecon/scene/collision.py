"""Collision boxes that follow a scene's real surfaces (MuJoCo mesh geoms collide as convex hulls).

The surface is voxelized (every triangle sampled finer than the voxel), then occupied voxels are
merged into axis-aligned boxes: runs along x, runs of equal runs along y, then along z. A wall or
floor becomes one box, furniture a few dozen. Only voxels whose samples sit alike inside them (per
axis, in quarters of a voxel) merge; each box is then shrunk to the samples it holds and padded by
the sample spacing. Every surface point is inside a box, and an axis-aligned surface's box stands a
quarter voxel in front of it. Whole voxels would put the physical surface up to 1.25 voxels in
front of the one the camera sees and the planner maps, eating the planner's safety margin.
The box count is bounded (coarser voxels) so that physics steps stay fast on sloped scans.
"""

from __future__ import annotations

import math

import numpy as np

from flightrecon.scene.types import Scene


SAMPLE_SPACING = 0.25  # surface samples per voxel edge: every surface point is this close (x pitch)


def _grid(scene: Scene, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Origin corner and shape of a voxel grid holding the scene with a voxel to spare."""
    v = np.asarray(scene.vertices, np.float64)
    origin = v.min(axis=0) - pitch
    return origin, np.ceil((v.max(axis=0) + pitch - origin) / pitch).astype(np.int64) + 1


def _surface_samples(scene: Scene, pitch: float):
    """Batches (N, 3) of a barycentric grid on every triangle with spacing <= SAMPLE_SPACING * pitch,
    so each surface point lies within that distance of a sample."""
    v = np.asarray(scene.vertices, np.float64)
    f = np.asarray(scene.faces, np.int64)
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
        chunk = max(1, 2_000_000 // len(wb))
        for start in range(0, len(A), chunk):
            sl = slice(start, start + chunk)
            pts = A[sl, None] + (B[sl, None] - A[sl, None]) * wb[None, :, None] \
                + (C[sl, None] - A[sl, None]) * wc[None, :, None]
            yield pts.reshape(-1, 3)


def surface_voxels(scene: Scene, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Boolean occupancy grid (X, Y, Z) of voxels holding surface samples, and its origin corner."""
    origin, dims = _grid(scene, pitch)
    occ = np.zeros(dims, bool)
    for pts in _surface_samples(scene, pitch):
        idx = np.floor((pts - origin) / pitch).astype(np.int64)
        occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    return occ, origin


def _sample_bounds(scene: Scene, pitch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Occupancy grid and origin as in `surface_voxels`, with the per-voxel bounds (X, Y, Z, 3) of
    its samples (lower, upper; +inf and -inf where a voxel holds none)."""
    origin, dims = _grid(scene, pitch)
    lower = np.full((*dims, 3), np.inf)
    upper = np.full((*dims, 3), -np.inf)
    lower_rows, upper_rows = lower.reshape(-1, 3), upper.reshape(-1, 3)
    for pts in _surface_samples(scene, pitch):
        flat = np.ravel_multi_index(np.floor((pts - origin) / pitch).astype(np.int64).T, dims)
        np.minimum.at(lower_rows, flat, pts)
        np.maximum.at(upper_rows, flat, pts)
    return np.isfinite(lower[..., 0]), origin, lower, upper


def merge_boxes(labels: np.ndarray) -> np.ndarray:
    """Cover the labelled voxels (nonzero; a boolean grid is one label) exactly with boxes, each of
    one label; rows of (x0, y0, z0, x1, y1, z1) voxel bounds."""
    X, Y, Z = labels.shape
    # runs of one label along x for every (y, z) line
    pad = np.zeros((X + 2, Y, Z), np.int64)
    pad[1:-1] = labels
    change = pad[1:] != pad[:-1]  # (X + 1, Y, Z): between pad[x] and pad[x + 1]
    sx, sy, sz = np.nonzero(change & (pad[1:] != 0))
    ex, ey, ez = np.nonzero(change & (pad[:-1] != 0))
    o1 = np.lexsort((sx, sy, sz))
    o2 = np.lexsort((ex, ey, ez))
    sx, sy, sz = sx[o1], sy[o1], sz[o1]
    runs = np.stack([sx, ex[o2], sy, sz, labels[sx, sy, sz]], axis=1)  # x0, x1 (exclusive), y, z, label
    # merge runs with equal (x0, x1, z, label) on consecutive y
    rects = _merge_consecutive(runs[:, [0, 1, 3, 4]], runs[:, 2])  # x0, x1, z, label, y0, y1
    # merge rects with equal (x0, x1, y0, y1, label) on consecutive z
    boxes = _merge_consecutive(rects[:, [0, 1, 4, 5, 3]], rects[:, 2])  # x0, x1, y0, y1, label, z0, z1
    x0, x1, y0, y1, _, z0, z1 = boxes.T
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


EXTENT_BINS = 4  # a box reaches at most 1/EXTENT_BINS of a voxel beyond the samples of any of its voxels


def _extent_labels(occ: np.ndarray, lower: np.ndarray, upper: np.ndarray, origin: np.ndarray,
                   pitch: float) -> np.ndarray:
    """Label each occupied voxel by where its samples lie inside it (per axis, lower and upper bound
    in quarters), so that merged boxes, shrunk to their samples, stay tight: a floor voxel that also
    holds the foot of a table leg does not lift the whole floor's box."""
    corner = origin + np.stack(np.nonzero(occ), axis=1) * pitch
    lo = np.clip(((lower[occ] - corner) / pitch * EXTENT_BINS).astype(np.int64), 0, EXTENT_BINS - 1)
    hi = np.clip(((upper[occ] - corner) / pitch * EXTENT_BINS).astype(np.int64), 0, EXTENT_BINS - 1)
    code = np.zeros(len(lo), np.int64)
    for column in np.hstack([lo, hi]).T:
        code = code * EXTENT_BINS + column
    labels = np.zeros(occ.shape, np.int64)
    labels[occ] = code + 1
    return labels


MAX_BOXES = 5000  # MuJoCo updates every geom each physics step: ~0.05 ms per 1000 boxes


def collision_boxes(scene: Scene, pitch: float = 0.05, max_boxes: int = MAX_BOXES) -> tuple[np.ndarray, float]:
    """World-frame boxes (N, 6): center xyz, half sizes xyz, covering the surface; and the pitch used.

    Sloped or curved surfaces of a scan merge poorly into axis-aligned boxes; while there are more
    than `max_boxes`, the voxel size doubles (coarser, still covering the surface)."""
    if not (math.isfinite(pitch) and pitch > 0):
        raise ValueError(f"collision voxel pitch must be positive, got {pitch}")
    while True:
        occ, origin, lower, upper = _sample_bounds(scene, pitch)
        b = merge_boxes(_extent_labels(occ, lower, upper, origin, pitch))
        if len(b) <= max_boxes or max(occ.shape) <= 4:
            break
        pitch *= 2.0
    pad = SAMPLE_SPACING * pitch  # a surface point is this close to a sample
    lo = np.empty((len(b), 3))
    hi = np.empty((len(b), 3))
    for i, (x0, y0, z0, x1, y1, z1) in enumerate(b):  # every voxel of a box holds samples
        lo[i] = lower[x0:x1, y0:y1, z0:z1].reshape(-1, 3).min(axis=0)
        hi[i] = upper[x0:x1, y0:y1, z0:z1].reshape(-1, 3).max(axis=0)
    lo -= pad
    hi += pad
    return np.hstack([(lo + hi) / 2, (hi - lo) / 2]), pitch

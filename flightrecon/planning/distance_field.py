"""Euclidean distance field over a voxel grid: the clearance oracle of planning.

Values are stored at voxel centers and are signed: positive in free voxels (distance to the nearest
blocked voxel's face), negative inside blocked ones. They come from scipy's exact Euclidean distance
transform between voxel centers, shifted by half a voxel so the zero crossing sits on the voxel faces
(for an axis-aligned wall this makes the estimate unbiased).

Accuracy: for a surface voxelized at size h (a voxel is blocked iff the surface passes through it),
the field differs from the true distance to the surface by about one voxel: it never reads more
than `accuracy` = h above the truth (measured: under 0.2 h), and may read up to about 1.5 h below it
near edges and corners (conservative). Inside closed obstacles the negative values are also
conservative (the surface shell is one to two voxels thick). Points outside the grid read as blocked
(negative: minus their distance to the grid box).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


class DistanceField:
    """Signed distance (m) sampled at the centers of a regular grid; `distance(points)` interpolates."""

    def __init__(self, values: np.ndarray, origin: np.ndarray, voxel_size: float):
        self.values = np.ascontiguousarray(values, dtype=np.float32)
        if self.values.ndim != 3:
            raise ValueError(f"distance grid must be 3D, got shape {self.values.shape}")
        self.origin = np.asarray(origin, float).reshape(3)
        self.voxel_size = float(voxel_size)
        self.shape = np.array(self.values.shape)
        self._flat = self.values.reshape(-1)
        self._box = self.bounds
        self._hi_center = (self.shape - 1).astype(float)
        self._i0_max = np.maximum(self.shape - 2, 0)
        nx, ny, nz = self.shape
        self._strides = (ny * nz if nx > 1 else 0, nz if ny > 1 else 0, 1 if nz > 1 else 0)
        self._row = np.array([ny * nz, nz, 1])

    @property
    def accuracy(self) -> float:
        """How far the field may exceed the true distance to a voxelized surface (one voxel).

        It may also read lower than the truth by up to about 1.5 voxels near edges and corners (the
        safe side); clearance checks compare the field against the required distance directly."""
        return self.voxel_size

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) [min, max] corners of the grid box."""
        return np.stack([self.origin, self.origin + self.shape * self.voxel_size])

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_blocked(cls, blocked: np.ndarray, origin: np.ndarray, voxel_size: float,
                     signed: bool = True) -> "DistanceField":
        """Field of a boolean grid (True = not flyable: occupied or unknown).

        `signed=False` skips the inside transform (half the cost): blocked voxels then read -h/2."""
        blocked = np.asarray(blocked, bool)
        h = float(voxel_size)
        if not blocked.any():
            # Nothing blocked inside the grid: distance to the grid boundary, which reads as blocked.
            values = _distance_to_box_faces(blocked.shape, h)
            return cls(values, origin, h)
        outside = ndimage.distance_transform_edt(~blocked, sampling=h).astype(np.float32)
        values = outside - np.float32(h / 2)
        if signed:
            inside = ndimage.distance_transform_edt(blocked, sampling=h).astype(np.float32)
            values[blocked] = -(inside[blocked] - np.float32(h / 2))
        else:
            values[blocked] = -np.float32(h / 2)
        return cls(values, origin, h)

    @classmethod
    def from_mesh(cls, mesh, voxel_size: float, bounds: np.ndarray,
                  free_seeds: np.ndarray | None = None, signed: bool = True) -> "DistanceField":
        """Field of a triangle mesh (e.g. the ground-truth scene) over the box `bounds` (2, 3).

        With `free_seeds` (K, 3), every voxel not connected to a seed through unblocked voxels is
        blocked too: object interiors and the outside of a closed room become obstacles."""
        blocked, origin = voxelize_mesh(mesh, voxel_size, bounds)
        if free_seeds is not None:
            blocked = block_unreachable(blocked, origin, voxel_size, free_seeds)
        return cls.from_blocked(blocked, origin, voxel_size, signed=signed)

    # ------------------------------------------------------------------ queries
    def _outside(self, p: np.ndarray) -> np.ndarray:
        """Distance of each point to the grid box (0 inside)."""
        lo, hi = self._box
        e = np.maximum(lo - p, 0) + np.maximum(p - hi, 0)
        return np.sqrt(np.einsum("ij,ij->i", e, e))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed clearance (m) of points (N, 3), trilinear between voxel centers -> (N,)."""
        p = np.asarray(points, float).reshape(-1, 3)
        g = np.clip((p - self.origin) / self.voxel_size - 0.5, 0.0, self._hi_center)
        i0 = np.minimum(g.astype(np.int64), self._i0_max)
        f = g - i0
        flat = self._flat
        sx, sy, sz = self._strides
        base = i0 @ self._row
        fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
        gz = 1 - fz
        c00 = flat[base] * gz + flat[base + sz] * fz
        c01 = flat[base + sy] * gz + flat[base + sy + sz] * fz
        c10 = flat[base + sx] * gz + flat[base + sx + sz] * fz
        c11 = flat[base + sx + sy] * gz + flat[base + sx + sy + sz] * fz
        d = (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx
        out = self._outside(p)
        return np.where(out > 0, np.minimum(d, -out), d)

    def distance_nearest(self, points: np.ndarray) -> np.ndarray:
        """Value of the voxel containing each point (no interpolation; cheapest query)."""
        p = np.asarray(points, float).reshape(-1, 3)
        idx = np.floor((p - self.origin) / self.voxel_size).astype(np.int64)
        inside = np.all((idx >= 0) & (idx < self.shape), axis=1)
        idx = np.clip(idx, 0, self.shape - 1)
        d = self.values[idx[:, 0], idx[:, 1], idx[:, 2]].astype(float)
        return np.where(inside, d, np.minimum(d, -self._outside(p)))

    def gradient(self, points: np.ndarray) -> np.ndarray:
        """Spatial gradient (N, 3) of the field (unit length away from the medial axis): points away
        from the nearest obstacle. Central differences of the trilinear field at a quarter voxel."""
        p = np.asarray(points, float).reshape(-1, 3)
        e = 0.25 * self.voxel_size
        grads = []
        for k in range(3):
            step = np.zeros(3)
            step[k] = e
            grads.append((self.distance(p + step) - self.distance(p - step)) / (2 * e))
        return np.stack(grads, axis=1)


def grid_for_bounds(bounds: np.ndarray, voxel_size: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Origin and shape of the voxel grid covering the box `bounds` (2, 3), aligned to voxel_size."""
    b = np.asarray(bounds, float).reshape(2, 3)
    if not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
        raise ValueError(f"grid bounds must be finite with max > min, got {b.tolist()}")
    h = float(voxel_size)
    origin = np.floor(b[0] / h) * h
    shape = tuple(int(n) for n in np.maximum(np.ceil((b[1] - origin) / h - 1e-9), 1).astype(int))
    return origin, shape


def voxelize_mesh(mesh, voxel_size: float, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boolean grid of voxels the surface passes through, and the grid origin.

    Each triangle is sampled on a barycentric lattice whose spacing along every edge is below h/2,
    so every surface point lies within h/(2 sqrt 3) of a sample; the samples' voxels are marked."""
    h = float(voxel_size)
    origin, shape = grid_for_bounds(bounds, h)
    blocked = np.zeros(shape, bool)
    tris = np.asarray(mesh.vertices, float)[np.asarray(mesh.faces, np.int64)]
    if len(tris) == 0:
        return blocked, origin
    edges = np.stack([tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0], tris[:, 2] - tris[:, 1]], 1)
    steps = np.maximum(np.ceil(np.linalg.norm(edges, axis=2).max(axis=1) / (h / 2)), 1).astype(int)
    dims = np.array(shape)
    for n in np.unique(steps):
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        uv = np.stack([i[keep], j[keep]], 1) / n  # (S, 2) barycentric lattice
        group = tris[steps == n]
        chunk = max(1, 2_000_000 // len(uv))  # bound peak memory for big triangles
        for s in range(0, len(group), chunk):
            t = group[s:s + chunk]
            pts = (t[:, None, 0] + uv[None, :, :1] * (t[:, None, 1] - t[:, None, 0])
                   + uv[None, :, 1:] * (t[:, None, 2] - t[:, None, 0])).reshape(-1, 3)
            idx = np.floor((pts - origin) / h).astype(np.int64)
            idx = idx[np.all((idx >= 0) & (idx < dims), axis=1)]
            blocked[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    return blocked, origin


def block_unreachable(blocked: np.ndarray, origin: np.ndarray, voxel_size: float,
                      free_seeds: np.ndarray) -> np.ndarray:
    """`blocked` plus every voxel not 6-connected through free voxels to one of the seed points."""
    labels, _ = ndimage.label(~blocked)
    seeds = np.asarray(free_seeds, float).reshape(-1, 3)
    idx = np.floor((seeds - origin) / voxel_size).astype(np.int64)
    ok = np.all((idx >= 0) & (idx < np.array(blocked.shape)), axis=1)
    keep = {int(labels[i, j, k]) for i, j, k in idx[ok]} - {0}
    if not keep:
        raise ValueError("no free seed point lies in a free voxel of the grid")
    return ~np.isin(labels, sorted(keep))


def _distance_to_box_faces(shape: tuple[int, ...], h: float) -> np.ndarray:
    """Distance of each voxel center to the nearest face of the grid box."""
    axes = [np.minimum(np.arange(n) + 0.5, n - 0.5 - np.arange(n)) * h for n in shape]
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    return np.minimum(np.minimum(gx, gy), gz).astype(np.float32)


__all__ = ["DistanceField", "grid_for_bounds", "voxelize_mesh", "block_unreachable"]

"""Quad-mesh builder for procedural scenes: tessellated planes, boxes and cylinders with baked colors.

Every surface is a regular grid of quads a few centimeters across, so per-vertex colors can carry
patterns (wood grain, tiles, text) the way Replica's scans do. Appearance functions receive the
metric surface coordinates (s, t) of each vertex and return RGB in [0, 1].
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

# (s, t) metric surface coordinates (N,) -> RGB (N, 3) in [0, 1]
Appearance = Callable[[np.ndarray, np.ndarray], np.ndarray]

HIDDEN = math.inf  # cell size of faces nobody sees (wall backs, undersides): one quad


class QuadMeshBuilder:
    """Accumulates vertices (with colors and normals) and quads (4 indices, counter-clockwise)."""

    def __init__(self) -> None:
        self._verts: list[np.ndarray] = []
        self._colors: list[np.ndarray] = []
        self._normals: list[np.ndarray] = []
        self._quads: list[np.ndarray] = []
        self._count = 0

    def plane(self, origin, u, v, cell: float, appearance: Appearance, normal=None) -> None:
        """Grid over the parallelogram origin + s*u + t*v (s, t in [0, 1]); faces +u x v."""
        origin, u, v = (np.asarray(a, float) for a in (origin, u, v))
        lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        if lu <= 0 or lv <= 0:
            return
        nu = 1 if math.isinf(cell) else max(1, math.ceil(lu / cell - 1e-9))
        nv = 1 if math.isinf(cell) else max(1, math.ceil(lv / cell - 1e-9))
        s = np.linspace(0.0, 1.0, nu + 1)
        t = np.linspace(0.0, 1.0, nv + 1)
        tt, ss = np.meshgrid(t, s, indexing="ij")  # (nv+1, nu+1), row-major along u
        ss, tt = ss.ravel(), tt.ravel()
        pts = origin + ss[:, None] * u + tt[:, None] * v
        n = np.cross(u, v) if normal is None else np.asarray(normal, float)
        n = n / np.linalg.norm(n)
        rgb = np.clip(appearance(ss * lu, tt * lv), 0.0, 1.0)
        i = np.arange(nu)
        j = np.arange(nv)
        jj, ii = np.meshgrid(j, i, indexing="ij")
        a = (jj * (nu + 1) + ii).ravel()
        quads = np.stack([a, a + 1, a + nu + 2, a + nu + 1], axis=1) + self._count
        self._verts.append(pts)
        self._colors.append(rgb)
        self._normals.append(np.broadcast_to(n, pts.shape))
        self._quads.append(quads)
        self._count += len(pts)

    def box(self, center, size, appearance: Appearance | dict, cell: float, R=None,
            hidden: tuple[str, ...] = ()) -> None:
        """Closed box; `appearance` per face key (+x, -x, +y, -y, +z, -z) or one for all;
        faces named in `hidden` get a single quad."""
        c = np.asarray(center, float)
        hx, hy, hz = (0.5 * float(x) for x in size)
        R = np.eye(3) if R is None else np.asarray(R, float)
        ex, ey, ez = R[:, 0], R[:, 1], R[:, 2]
        faces = {  # origin corner, u, v with u x v pointing outward
            "+x": (c + hx * ex - hy * ey - hz * ez, 2 * hy * ey, 2 * hz * ez),
            "-x": (c - hx * ex + hy * ey - hz * ez, -2 * hy * ey, 2 * hz * ez),
            "+y": (c + hx * ex + hy * ey - hz * ez, -2 * hx * ex, 2 * hz * ez),
            "-y": (c - hx * ex - hy * ey - hz * ez, 2 * hx * ex, 2 * hz * ez),
            "+z": (c - hx * ex - hy * ey + hz * ez, 2 * hx * ex, 2 * hy * ey),
            "-z": (c - hx * ex + hy * ey - hz * ez, 2 * hx * ex, -2 * hy * ey),
        }
        for key, (o, u, v) in faces.items():
            app = appearance[key] if isinstance(appearance, dict) else appearance
            self.plane(o, u, v, HIDDEN if key in hidden else cell, app)

    def cylinder(self, base, radius_bottom: float, radius_top: float, height: float,
                 appearance: Appearance, segments: int = 16, cell: float = 0.05) -> None:
        """Closed (possibly conical) cylinder standing on `base`, axis +z; side split along z."""
        base = np.asarray(base, float)
        segments += segments % 2  # caps are fans of quads over pairs of segments
        ang = np.linspace(0.0, 2 * math.pi, segments + 1)
        nz = max(1, math.ceil(height / cell))
        z = np.linspace(0.0, height, nz + 1)
        r = radius_bottom + (radius_top - radius_bottom) * z / height
        zz, aa = np.meshgrid(z, ang, indexing="ij")  # (nz+1, seg+1)
        rr = np.broadcast_to(r[:, None], zz.shape)
        pts = base + np.stack([rr * np.cos(aa), rr * np.sin(aa), zz], axis=-1).reshape(-1, 3)
        slope = (radius_bottom - radius_top) / height
        nrm = np.stack([np.cos(aa), np.sin(aa), np.full_like(aa, slope)], axis=-1).reshape(-1, 3)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        circumference = 2 * math.pi * max(radius_bottom, radius_top)
        rgb = np.clip(appearance((aa / (2 * math.pi) * circumference).ravel(), zz.ravel()), 0, 1)
        cols = segments + 1
        i = np.arange(segments)
        k = np.arange(nz)
        kk, ii = np.meshgrid(k, i, indexing="ij")
        a = (kk * cols + ii).ravel()
        quads = np.stack([a, a + 1, a + cols + 1, a + cols], axis=1) + self._count
        self._verts.append(pts)
        self._colors.append(rgb)
        self._normals.append(nrm)
        self._quads.append(quads)
        self._count += len(pts)
        for zc, rc, up in ((height, radius_top, True), (0.0, radius_bottom, False)):
            self._cap(base + [0, 0, zc], rc, ang[:-1], up, appearance)

    def _cap(self, center, radius, ang, up: bool, appearance: Appearance) -> None:
        ring = center + radius * np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
        pts = np.vstack([center[None], ring])
        rgb = np.clip(appearance(pts[:, 0] - center[0], pts[:, 1] - center[1]), 0, 1)
        n = len(ang)
        k = np.arange(0, n, 2)
        quads = np.stack([np.zeros_like(k), 1 + k, 1 + (k + 1) % n, 1 + (k + 2) % n], axis=1)
        if not up:
            quads = quads[:, ::-1]
        self._verts.append(pts)
        self._colors.append(rgb)
        self._normals.append(np.broadcast_to([0.0, 0.0, 1.0 if up else -1.0], pts.shape))
        self._quads.append(quads + self._count)
        self._count += len(pts)

    def build(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(vertices float32 (V,3), colors uint8 (V,3), normals float32 (V,3), quads int32 (Q,4))."""
        verts = np.vstack(self._verts).astype(np.float32)
        colors = np.round(np.vstack(self._colors) * 255.0).astype(np.uint8)
        normals = np.vstack(self._normals).astype(np.float32)
        quads = np.vstack(self._quads).astype(np.int32)
        return verts, colors, normals, quads

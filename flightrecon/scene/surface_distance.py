"""Exact distance from points to a scene's triangles: the ground truth of flight clearance.

The voxel distance field (planning.distance_field) is what the planner can afford to query millions
of times, but as an oracle it is off by up to a voxel and a half near edges and corners. Clearance is
what we report to say whether a flight was safe, so it is measured exactly: Open3D's
RaycastingScene holds the triangles in a BVH (Embree) and answers the closest-point query per point
in microseconds. The BVH is built on first use and not pickled (it is rebuilt after a copy).
"""

from __future__ import annotations

import numpy as np

from flightrecon.errors import DataError
from flightrecon.open3d_import import open3d_module


class SurfaceDistance:
    """Unsigned distance (m) from points to the triangles of a mesh (anything with vertices, faces)."""

    def __init__(self, mesh) -> None:
        self.vertices = np.ascontiguousarray(np.asarray(mesh.vertices, np.float32).reshape(-1, 3))
        self.faces = np.ascontiguousarray(np.asarray(mesh.faces, np.uint32).reshape(-1, 3))
        if len(self.faces) == 0:
            raise DataError("exact clearance needs a mesh with triangles; this one has none")
        self._scene = None

    def __getstate__(self) -> dict:
        return {"vertices": self.vertices, "faces": self.faces, "_scene": None}

    def raycasting_scene(self):
        """The mesh's Open3D RaycastingScene (built on first use): for rays cast at the same triangles."""
        if self._scene is None:
            o3d = open3d_module()
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(o3d.core.Tensor(self.vertices), o3d.core.Tensor(self.faces))
            self._scene = scene
        return self._scene

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of each point (N, 3) to the nearest triangle -> (N,) float64; NaN for non-finite points."""
        p = np.asarray(points, float).reshape(-1, 3)
        out = np.full(len(p), np.nan)
        ok = np.all(np.isfinite(p), axis=1)
        if ok.any():
            o3d = open3d_module()
            q = o3d.core.Tensor(np.ascontiguousarray(p[ok], np.float32))
            out[ok] = self.raycasting_scene().compute_distance(q).numpy()
        return out

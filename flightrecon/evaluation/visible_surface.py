"""The part of the ground-truth surface that can be seen from the scene's free space.

Completion must measure the whole room, not only what a few evaluation views happen to see, and
must not count surface no camera in the room could ever see: the outer faces of walls and slabs,
the bottom of a box standing on the floor, faces inside closed furniture, the second copy of a
doubled face behind its twin. A surface point is visible from the free space exactly when the free
space reaches it, so the test is local: the room's free space is the connected empty region of the
voxelized surface that holds the take-off point (flightrecon.scene.free_space; in an open scan,
bounded by its extent and with its holes closed, so the outer side of a holey wall stays hidden),
and a point is visible when the voxel a little off the surface along its face normal (either side:
scans wind faces inconsistently) belongs to it. Exact up to the voxel: gaps narrower than about one
voxel count as closed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from flightrecon.scene.free_space import FreeSpace
from flightrecon.scene.types import Scene

OFFSET = 1.5  # voxels off the surface at which the free space is probed


@dataclass(frozen=True)
class VisibleSurface:
    points: np.ndarray  # (M, 3) area-uniform samples of the visible surface
    visible_area_m2: float
    total_area_m2: float


def visible_surface(scene: Scene, free: FreeSpace, count: int, seed: int = 0) -> VisibleSurface:
    """`count` area-uniform samples of the whole ground-truth surface, kept where the room's free
    space reaches them."""
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
    pts, face = trimesh.sample.sample_surface(mesh, count, seed=seed)
    normals = np.asarray(mesh.face_normals)[face]
    probe = OFFSET * free.pitch * normals
    seen = free.contains(pts + probe) | free.contains(pts - probe)
    total = float(mesh.area)
    return VisibleSurface(np.asarray(pts[seen], float), total * float(seen.mean()), total)

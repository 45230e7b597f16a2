"""The part of the ground-truth surface that can be seen from the scene's free space.

Completion must measure the whole room, not only what a few evaluation views happen to see, and
must not count surface no camera in the room could ever see: the outer faces of walls and slabs,
the bottom of a box standing on the floor, faces inside closed furniture, the second copy of a
doubled face behind its twin. A surface point is visible from the free space exactly when the free
space reaches it, so the test is local: the room's free space is the connected empty region of the
voxelized surface that holds the take-off point, and a point is visible when the voxel a little
off the surface along its face normal (either side: scans wind faces inconsistently) belongs to it.
Exact up to the voxel: gaps narrower than about one voxel count as closed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

from flightrecon.scene.collision import surface_voxels
from flightrecon.scene.types import Scene

PITCH = 0.03  # m, voxel of the free-space test
OFFSET = 1.5  # voxels off the surface at which the free space is probed


@dataclass(frozen=True)
class VisibleSurface:
    points: np.ndarray  # (M, 3) area-uniform samples of the visible surface
    visible_area_m2: float
    total_area_m2: float


@dataclass(frozen=True)
class FreeSpace:
    """The room's free space: the empty voxels connected to the take-off point."""

    grid: np.ndarray  # (X, Y, Z) bool
    origin: np.ndarray  # (3,) corner of voxel (0, 0, 0)
    pitch: float

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) True where a point (N, 3) lies in a free voxel of the room."""
        idx = np.floor((np.atleast_2d(points) - self.origin) / self.pitch).astype(np.int64)
        inside = ((idx >= 0) & (idx < self.grid.shape)).all(axis=1)
        out = np.zeros(len(idx), bool)
        out[inside] = self.grid[idx[inside, 0], idx[inside, 1], idx[inside, 2]]
        return out


def _free_regions(scene: Scene, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Connected empty regions of the voxelized surface: labels (X, Y, Z), 0 on the surface, and the
    grid's origin corner."""
    occ, origin = surface_voxels(scene, pitch)
    labels, _ = ndimage.label(~occ)
    return labels, origin


def room_free_space(scene: Scene, seed_point: np.ndarray, pitch: float = PITCH) -> FreeSpace:
    """The empty voxels of the voxelized surface connected to `seed_point` (the take-off point)."""
    labels, origin = _free_regions(scene, pitch)
    idx = np.floor((np.asarray(seed_point, float) - origin) / pitch).astype(np.int64)
    if (idx < 0).any() or (idx >= labels.shape).any() or labels[tuple(idx)] == 0:
        raise ValueError(f"the take-off point {np.round(seed_point, 3).tolist()} is not in the free space "
                         f"of scene '{scene.name}'")
    return FreeSpace(labels == labels[tuple(idx)], origin, pitch)


def largest_free_space(scene: Scene, box: np.ndarray, pitch: float = PITCH) -> FreeSpace:
    """The connected empty region that fills most of `box` (2, 3), the room's box: the room's free
    space found without a point in it, to choose the take-off point by (the default one may lie in
    furniture or outside the walls). Equal to `room_free_space` seeded anywhere inside it."""
    labels, origin = _free_regions(scene, pitch)
    lo = np.clip(np.floor((box[0] - origin) / pitch).astype(np.int64), 0, labels.shape)
    hi = np.clip(np.ceil((box[1] - origin) / pitch).astype(np.int64), 0, labels.shape)
    inside = labels[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]].ravel()
    counts = np.bincount(inside[inside > 0], minlength=1)
    if counts.max(initial=0) == 0:
        return FreeSpace(np.zeros(labels.shape, bool), origin, pitch)
    return FreeSpace(labels == int(np.argmax(counts)), origin, pitch)


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

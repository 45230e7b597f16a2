"""The room's free space: the empty space around the take-off point that the scene's surface bounds.

The surface is voxelized (`collision.surface_voxels`) and the room is the connected empty region
that holds the take-off point. A closed room is exactly that, to the voxel. A scan is rarely closed:
through a hole in a wall, a missing ceiling or a missing floor patch the empty voxels reach the
whole grid, and the room would be everything. When the region reaches the grid's edge, the room is
therefore bounded twice:

- by the scan's own extent (the box of its surface): there is no room where nothing was scanned,
  so an open ceiling ends at the top of the walls and a missing floor at the lowest surface;
- by closing holes narrower than twice `HOLE_RADIUS`: where a ball of that radius fits, the empty
  space is cut into the regions such balls can roll through; a region other than the take-off
  point's is beyond a hole, and the voxels nearer to its balls than to the room's are taken out,
  which plugs the hole at its narrowest. A doorway (0.8 m and wider) stays open. Elsewhere the room
  keeps every empty voxel, so corners and the space under furniture stay in.

A part of an open scan's room reached only through an opening narrower than the hole size counts
as beyond it; a thin cavity (between two layers of a wall) behind a hole stays in the room.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from flightrecon.scene.collision import surface_voxels
from flightrecon.scene.types import Scene

PITCH = 0.03  # m, voxel of the free space the evaluation uses
HOLE_RADIUS = 0.35  # m: holes up to 0.7 m across are closed (scan holes), doorways stay open
MIN_ROOM_SHARE = 0.5  # a take-off point's own region is the room when it holds this share of the other


@dataclass(frozen=True)
class FreeSpace:
    """The room's free voxels, and whether the surface alone encloses them (else the room was
    bounded by the scan's extent and its holes were closed)."""

    grid: np.ndarray  # (X, Y, Z) bool
    origin: np.ndarray  # (3,) corner of voxel (0, 0, 0)
    pitch: float
    enclosed: bool = True

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) True where a point (N, 3) lies in a free voxel of the room."""
        idx = np.floor((np.atleast_2d(points) - self.origin) / self.pitch).astype(np.int64)
        inside = ((idx >= 0) & (idx < self.grid.shape)).all(axis=1)
        out = np.zeros(len(idx), bool)
        out[inside] = self.grid[idx[inside, 0], idx[inside, 1], idx[inside, 2]]
        return out

    @property
    def volume_m3(self) -> float:
        return float(self.grid.sum()) * self.pitch ** 3


def room_free_space(scene: Scene, seed_point: np.ndarray, pitch: float = PITCH,
                    hole_radius: float = HOLE_RADIUS) -> FreeSpace:
    """The room around `seed_point` (the take-off point) at voxel size `pitch` (m)."""
    occ, origin = surface_voxels(scene, pitch)
    return _room(scene, occ, origin, pitch, _voxel(seed_point, origin, pitch), hole_radius, seed_point)


def room_for_takeoff(scene: Scene, point: np.ndarray, box: np.ndarray, pitch: float = PITCH,
                     hole_radius: float = HOLE_RADIUS) -> FreeSpace:
    """The room to choose a take-off point in: the empty region around `point` (the default hover
    point), unless the point lies in the surface or its region is a pocket (a cabinet's inside, under
    MIN_ROOM_SHARE of the other); then the region found without a point: the connected empty region
    that fills most of `box` (2, 3), the room's box, bounded as `room_free_space` bounds it from its
    most open voxel (empty when the box holds no empty voxel). A turned open scan leaves empty corners
    of its box outside the walls, which that region may be, so the point's own region comes first."""
    occ, origin = surface_voxels(scene, pitch)
    empty, _ = ndimage.label(~occ)
    largest = _largest_room(scene, occ, origin, pitch, empty, np.asarray(box, float), hole_radius)
    try:
        around = _room(scene, occ, origin, pitch, _voxel(point, origin, pitch), hole_radius, point, empty)
    except ValueError:  # the point is in a surface voxel
        return largest
    return around if around.volume_m3 >= MIN_ROOM_SHARE * largest.volume_m3 else largest


def _largest_room(scene: Scene, occ: np.ndarray, origin: np.ndarray, pitch: float, empty: np.ndarray,
                  box: np.ndarray, hole_radius: float) -> FreeSpace:
    """The room that fills most of `box`, from the labels `empty` of the empty voxels (`room_for_takeoff`)."""
    in_box = _within(box, origin, pitch, occ.shape) & (empty > 0)
    counts = np.bincount(empty[in_box], minlength=1)
    if counts.max(initial=0) == 0:
        return FreeSpace(np.zeros(occ.shape, bool), origin, pitch)
    # its most open voxel within the scan's extent, which bounding an open scan keeps
    region = in_box & (empty == int(np.argmax(counts))) & _within(scene.bounds, origin, pitch, occ.shape)
    if not region.any():
        return FreeSpace(np.zeros(occ.shape, bool), origin, pitch)
    clearance = np.where(region, ndimage.distance_transform_edt(~occ), -1.0)
    seed = tuple(int(i) for i in np.unravel_index(int(np.argmax(clearance)), occ.shape))
    return _room(scene, occ, origin, pitch, seed, hole_radius, origin + (np.array(seed) + 0.5) * pitch, empty)


def _voxel(point: np.ndarray, origin: np.ndarray, pitch: float) -> tuple:
    return tuple(np.floor((np.asarray(point, float) - origin) / pitch).astype(np.int64))


def _room(scene: Scene, occ: np.ndarray, origin: np.ndarray, pitch: float, seed: tuple, hole_radius: float,
          seed_point, empty: np.ndarray | None = None) -> FreeSpace:
    """The empty region holding voxel `seed` (`empty`: the labels of ~occ, if already made); bounded by
    the scan's extent and its holes closed when it reaches the grid's edge (the module docstring)."""
    room = _component(~occ, seed, scene.name, seed_point, empty)
    if not _touches_edge(room):
        return FreeSpace(room, origin, pitch, enclosed=True)
    free = ~occ & _within(scene.bounds, origin, pitch, occ.shape)
    room = _component(free & ~_beyond_holes(free, seed, hole_radius / pitch), seed, scene.name, seed_point)
    return FreeSpace(room, origin, pitch, enclosed=False)


def _component(free: np.ndarray, seed: tuple, name: str, seed_point,
               labels: np.ndarray | None = None) -> np.ndarray:
    """The connected region of `free` that holds voxel `seed` (`labels`: those of `free`, if made)."""
    inside = all(0 <= i < n for i, n in zip(seed, free.shape))
    if labels is None:
        labels, _ = ndimage.label(free)
    if not inside or labels[seed] == 0:
        raise ValueError(f"the take-off point {np.round(seed_point, 3).tolist()} is not in the free space of "
                         f"scene '{name}': move the scene's spawn or set sim.takeoff_height")
    return labels == labels[seed]


def _touches_edge(region: np.ndarray) -> bool:
    return any(region.take(i, axis=a).any() for a in range(3) for i in (0, -1))


def _within(bounds: np.ndarray, origin: np.ndarray, pitch: float, shape: tuple) -> np.ndarray:
    """Voxels whose centre lies in the box `bounds` (2, 3)."""
    centre = [origin[a] + (np.arange(shape[a]) + 0.5) * pitch for a in range(3)]
    x, y, z = [(c >= bounds[0, a]) & (c <= bounds[1, a]) for a, c in enumerate(centre)]
    return x[:, None, None] & y[None, :, None] & z[None, None, :]


def _beyond_holes(free: np.ndarray, seed: tuple, radius: float) -> np.ndarray:
    """Free voxels on the far side of holes narrower than 2 * `radius` (voxels) from voxel `seed`:
    those within a ball's reach of a ball centre not connected to the seed's, and nearer to it than
    to any of the seed's."""
    centres = ndimage.distance_transform_edt(free) > radius  # where a ball of the hole radius fits
    labels, n = ndimage.label(centres)
    if n == 0:
        return np.zeros_like(free)
    reach, nearest = ndimage.distance_transform_edt(labels == 0, return_indices=True)
    owner = labels[tuple(nearest)]
    # a voxel more than the ball's reach: a rim voxel of the hole that no ball centre quite reaches
    return free & (reach <= radius + 1) & (owner != owner[seed])

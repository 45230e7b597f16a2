"""Floor and ceiling heights of a z-up scene, from its metadata or from its own geometry.

Procedural scenes know theirs (`floor_z`, `ceiling_z` in the metadata). A scan does not, and many
have no ceiling at all (ScanNet-style scans: walls cut at 1-2 m), so the mesh bounds are not the
room. Here the horizontal surface area (faces within ~18 deg of level, either winding, since
scans orient normals inconsistently) is binned by height: the floor is the lowest bin holding a
large share of the largest bin's area; the ceiling is the highest such bin at least a room's
minimal height above the floor that covers a good part of the floor's area, else there is none.
A mesh with thick floor and ceiling slabs (synthetic rooms) has two large layers a slab apart at
each: the room's are the inner ones, the upper layer at the floor and the lower at the ceiling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flightrecon.scene.types import Scene

BIN = 0.05  # m, height bins of the horizontal area
HORIZONTAL = 0.95  # |n_z| of a face counted as horizontal
LARGE = 0.2  # a floor or ceiling bin holds at least this share of the largest bin's area
CEILING_COVER = 0.3  # a ceiling covers at least this share of the floor's area
MIN_ROOM_HEIGHT = 1.8  # m; a horizontal layer lower than this above the floor is furniture
SLAB = 0.3  # m; large layers this close to the lowest (highest) one are faces of the same slab


@dataclass(frozen=True)
class Levels:
    floor_z: float
    ceiling_z: float | None  # None: the scene has no ceiling
    source: str  # "metadata" or "geometry"


def scene_levels(scene: Scene) -> Levels:
    """The scene's floor and ceiling heights (m, world z)."""
    meta = scene.meta or {}
    if "floor_z" in meta:
        ceiling = meta.get("ceiling_z")
        return Levels(float(meta["floor_z"]), None if ceiling is None else float(ceiling), "metadata")
    return _levels_from_geometry(scene.vertices, scene.faces)


def _levels_from_geometry(vertices: np.ndarray, faces: np.ndarray) -> Levels:
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    area = 0.5 * norm
    flat = np.abs(cross[:, 2]) > HORIZONTAL * np.maximum(norm, 1e-30)
    z_lo = float(vertices[:, 2].min())
    if not flat.any():
        return Levels(z_lo, None, "geometry")
    z = tri[flat, :, 2].mean(axis=1)
    # a face's mean height can fall a rounding error below the lowest vertex: it belongs to bin 0
    bins = np.maximum(np.floor((z - z_lo) / BIN), 0).astype(np.int64)
    hist = np.bincount(bins, weights=area[flat])
    slab = int(round(SLAB / BIN))
    large = np.flatnonzero(hist >= LARGE * hist.max())
    floor_bin = int(large[large <= large[0] + slab][-1])
    floor_z = _layer_height(z, area[flat], bins, floor_bin)
    high = large[(z_lo + large * BIN >= floor_z + MIN_ROOM_HEIGHT) & (hist[large] >= CEILING_COVER * hist[floor_bin])]
    if not len(high):
        return Levels(floor_z, None, "geometry")
    ceil_bin = int(high[high >= high[-1] - slab][0])
    return Levels(floor_z, _layer_height(z, area[flat], bins, ceil_bin), "geometry")


def _layer_height(z: np.ndarray, area: np.ndarray, bins: np.ndarray, b: int) -> float:
    """Area-weighted mean height of the horizontal faces in bin `b`."""
    return float(np.average(z[bins == b], weights=area[bins == b]))

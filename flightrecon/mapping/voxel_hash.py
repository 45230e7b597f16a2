"""Voxel hashing of splat centers, for the paper's gamma rejection of new splats.

Keys pack the integer voxel coordinates into one int64 (21 bits per axis, +-1048576 voxels, i.e.
+-52 km at 5 cm), so set membership is a sorted-array search; the set is rebuilt from the current
centers whenever it is needed because optimization moves the splats.
"""

from __future__ import annotations

import numpy as np

_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1


def voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """(N, 3) points -> (N,) int64 keys of the voxels of side `voxel` that hold them."""
    ijk = np.floor(np.asarray(points, np.float64) / voxel).astype(np.int64) + _OFFSET
    ijk &= _MASK
    return (ijk[:, 0] << (2 * _BITS)) | (ijk[:, 1] << _BITS) | ijk[:, 2]


def occupied(keys: np.ndarray, existing_sorted: np.ndarray) -> np.ndarray:
    """Boolean mask of `keys` that appear in the sorted unique array `existing_sorted`."""
    if existing_sorted.size == 0:
        return np.zeros(keys.shape, bool)
    pos = np.searchsorted(existing_sorted, keys)
    pos = np.minimum(pos, existing_sorted.size - 1)
    return existing_sorted[pos] == keys


def reject_near(new_points: np.ndarray, existing_points: np.ndarray, voxel: float,
                one_per_voxel: bool = False, blocked: np.ndarray | None = None) -> np.ndarray:
    """Indices (ascending) of `new_points` whose voxel holds none of `existing_points` and is not
    among the sorted keys `blocked`.

    With `one_per_voxel`, of new points sharing a free voxel only the first (in order) is kept.
    """
    keys = voxel_keys(new_points, voxel)
    taken = np.unique(voxel_keys(existing_points, voxel))
    if blocked is not None and blocked.size:
        taken = np.union1d(taken, blocked)
    cand = np.nonzero(~occupied(keys, taken))[0]
    if not one_per_voxel:
        return cand
    _, first = np.unique(keys[cand], return_index=True)
    return np.sort(cand[first])

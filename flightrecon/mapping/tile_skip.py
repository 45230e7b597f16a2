"""Which tiles a mapping iteration renders (mapper.skip_tiles).

After a frame's update most of its remaining color error sits in a few tiles
(results/speed/issue56/part7): an iteration can leave out the tiles that already match the frame
and spend the rasterizer's time where the map is still wrong. A frame's tile errors are those of
its latest render, per tile (a left-out tile keeps the error it had when last rendered); every
`skip_full_every`-th iteration on a frame renders every tile and so refreshes them all.
"""

from __future__ import annotations

import numpy as np
import torch

from flightrecon.render.api import TILE, tile_grid


def tile_errors(color: torch.Tensor, target: torch.Tensor) -> np.ndarray:
    """Summed mean-absolute color error [rows, cols] of each TILE x TILE tile of [H,W,3] images."""
    H, W = color.shape[:2]
    rows, cols = tile_grid(W, H)
    err = torch.zeros(rows * TILE, cols * TILE, dtype=torch.float64)
    err[:H, :W] = (color.detach() - target).abs().mean(-1).double().cpu()
    return err.reshape(rows, TILE, cols, TILE).sum((1, 3)).numpy()


def tiles_to_keep(errors: np.ndarray, share: float) -> np.ndarray:
    """bool [rows, cols]: every tile but the round(share x tiles) of lowest error, and at least the one
    of highest (ties: the first in row order are left out)."""
    flat = errors.ravel()
    keep = np.ones(flat.size, bool)
    keep[np.argsort(flat, kind="stable")[:min(int(round(share * flat.size)), flat.size - 1)]] = False
    return keep.reshape(errors.shape)

"""Frames kept for replay, compactly: uint8 color and uint16 millimeter depth (0 = invalid).

About 0.5 MB per 320x240 frame instead of 1.5 MB as float32; millimeter quantization is well below
the depth noise the map can resolve. A frame is expanded back to float tensors when replayed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

_MM = 1000.0


@dataclass(frozen=True)
class StoredFrame:
    rgb: torch.Tensor  # (H, W, 3) uint8
    depth_mm: torch.Tensor  # (H, W) uint16 millimeters stored as int16 bits (torch lacks uint16 ops)
    K: torch.Tensor  # (3, 3) float32
    viewmat: torch.Tensor  # (4, 4) float32 world-to-camera
    T_wc: np.ndarray  # (4, 4) float64 camera-to-world


@dataclass(frozen=True)
class Window:
    """A pixel rectangle of a frame: columns x0 .. x0 + width - 1, rows y0 .. y0 + height - 1."""

    x0: int
    y0: int
    width: int
    height: int

    @property
    def rows(self) -> slice:
        return slice(self.y0, self.y0 + self.height)

    @property
    def cols(self) -> slice:
        return slice(self.x0, self.x0 + self.width)


# A block whose depths spread by more than this share of their mean straddles a depth edge (or a
# surface seen nearly edge-on): its mean lies on no surface, so the block is no depth evidence.
BLOCK_DEPTH_SPREAD = 0.05


def downsample(rgb: torch.Tensor, depth: torch.Tensor, factor: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Color [H, W, 3] and depth [H, W, 1] (0: invalid) at 1/factor of the width and height, one pixel
    per factor x factor block (rows and columns past the last whole block are dropped): the block's
    mean color, and its mean depth where every depth of the block is valid and they spread by at most
    BLOCK_DEPTH_SPREAD of that mean, else 0. The camera of the result is `scaled_intrinsics`."""
    if factor == 1:
        return rgb, depth
    f = int(factor)
    h, w = depth.shape[0] // f, depth.shape[1] // f
    if h == 0 or w == 0:
        raise ValueError(f"downsample: a {depth.shape[1]}x{depth.shape[0]} frame has no whole {f}x{f} block")
    color = rgb[:h * f, :w * f].reshape(h, f, w, f, 3).mean(dim=(1, 3))
    blocks = depth[:h * f, :w * f, 0].reshape(h, f, w, f)
    low, high, mean = blocks.amin(dim=(1, 3)), blocks.amax(dim=(1, 3)), blocks.mean(dim=(1, 3))
    agree = (low > 0) & (high - low <= BLOCK_DEPTH_SPREAD * mean)
    return color, torch.where(agree, mean, torch.zeros_like(mean))[..., None]


def scaled_intrinsics(K: torch.Tensor, factor: int) -> torch.Tensor:
    """The intrinsics of the image `downsample` makes: pixel coordinates (centers at +0.5) divide by
    the factor, so the first two rows of K do (K itself at factor 1, as `downsample`)."""
    if factor == 1:
        return K
    Ks = K.clone()
    Ks[:2] /= factor
    return Ks


def window_intrinsics(K: torch.Tensor, window: Window) -> torch.Tensor:
    """The intrinsics of the camera that sees just `window`: the principal point moves by its corner."""
    Kw = K.clone()
    Kw[0, 2] -= window.x0
    Kw[1, 2] -= window.y0
    return Kw


def compact_frame(rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray,
                  valid: np.ndarray) -> StoredFrame:
    """Quantize a frame; depth outside `valid` is stored as 0."""
    rgb8 = np.clip(np.round(np.asarray(rgb, np.float32) * 255.0), 0, 255).astype(np.uint8)
    mm = np.where(valid, np.round(np.nan_to_num(depth) * _MM), 0.0)
    mm = np.clip(mm, 0, np.iinfo(np.uint16).max).astype(np.uint16)
    viewmat = np.linalg.inv(np.asarray(T_wc, np.float64))
    return StoredFrame(torch.from_numpy(rgb8), torch.from_numpy(mm.view(np.int16)),
                       torch.as_tensor(K, dtype=torch.float32), torch.as_tensor(viewmat, dtype=torch.float32),
                       np.asarray(T_wc, np.float64).copy())


def expand_frame(f: StoredFrame, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Float rgb [H, W, 3] in [0, 1] and depth [H, W, 1] in meters (0 invalid) on `device`."""
    rgb = f.rgb.to(device).to(torch.float32) / 255.0
    depth = (f.depth_mm.to(device).to(torch.int32) & 0xFFFF).to(torch.float32) / _MM
    return rgb, depth.unsqueeze(-1)

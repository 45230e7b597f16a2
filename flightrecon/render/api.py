"""`render(...)`: the one functional, batched 2DGS rendering entry point, and backend dispatch."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import torch
from torch import Tensor

from flightrecon.errors import DataError, FlightReconError

OUTPUTS = ("features", "alpha", "depth", "median_depth", "normal", "normal_world", "distortion")
BACKENDS = ("auto", "cpu", "cuda", "reference")
TILE = 16  # the cpu rasterizer's tile side (csrc/rasterize.h, TS): the unit of `keep_tiles`


def tile_grid(width: int, height: int) -> tuple[int, int]:
    """(rows, columns) of TILE x TILE tiles that cover a width x height image."""
    return -(-height // TILE), -(-width // TILE)


def tile_pixels(keep_tiles: Tensor, width: int, height: int) -> Tensor:
    """A [C,rows,cols] tile mask as a [C,height,width,1] pixel mask."""
    pixels = keep_tiles.repeat_interleave(TILE, 1).repeat_interleave(TILE, 2)
    return pixels[:, :height, :width, None]


@dataclass
class RenderOutput:
    """Images are [C,H,W,k]; fields not requested are None. radii [C,N] int, 0 = not visible."""

    features: Optional[Tensor] = None
    alpha: Optional[Tensor] = None
    depth: Optional[Tensor] = None
    median_depth: Optional[Tensor] = None
    normal: Optional[Tensor] = None
    normal_world: Optional[Tensor] = None
    distortion: Optional[Tensor] = None
    radii: Optional[Tensor] = None


def resolve_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise FlightReconError(f"render: unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if backend == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if backend == "cuda" and not torch.cuda.is_available():
        raise FlightReconError("render: backend 'cuda' requested but torch sees no CUDA device")
    return backend


def check_inputs(means, quats, log_scales, opacity_logits, features, viewmats, Ks, width, height,
                 near, far, outputs) -> None:
    """Shape and value checks: one clear message instead of a crash deep in a kernel."""
    N = means.shape[0] if means.dim() == 2 else -1
    C = viewmats.shape[0] if viewmats.dim() == 3 else -1
    expect = {"means": (means, (N, 3)), "quats": (quats, (N, 4)), "log_scales": (log_scales, (N, 2)),
              "opacity_logits": (opacity_logits, (N,)), "viewmats": (viewmats, (C, 4, 4)),
              "Ks": (Ks, (C, 3, 3))}
    for name, (t, shape) in expect.items():
        if N < 0 or C < 0 or tuple(t.shape) != shape:
            raise FlightReconError(f"render: {name} has shape {tuple(t.shape)}, expected {shape} "
                                   "(N splats, C cameras)")
    if not ((features.dim() == 2 and features.shape[0] == N)
            or (features.dim() == 3 and features.shape[:2] == (C, N))):
        raise FlightReconError(f"render: features has shape {tuple(features.shape)}, expected "
                               f"[N,D] or [C,N,D] with N={N}, C={C}")
    if width < 1 or height < 1:
        raise FlightReconError(f"render: image size {width}x{height} must be at least 1x1")
    if not (0 < near < far):
        raise FlightReconError(f"render: need 0 < near < far, got near={near}, far={far}")
    bad = [o for o in outputs if o not in OUTPUTS]
    if bad:
        raise FlightReconError(f"render: unknown outputs {bad} (choose from {', '.join(OUTPUTS)})")
    expect["features"] = (features, None)
    for name, (t, _) in expect.items():
        if not all_finite(t):
            raise DataError(f"render: {name} contains NaN or inf")


def all_finite(t: Tensor) -> bool:
    """No NaN or inf in `t`. A NaN or inf element makes the sum NaN or inf, so a finite sum settles it
    in one cheap reduction (isfinite().all() cost ~0.9 ms on 100k quaternions, per render call); a
    non-finite sum may be an overflow of finite values, so only then is every element checked."""
    return bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all())


def render(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
           features: Tensor, viewmats: Tensor, Ks: Tensor, width: int, height: int,
           near: float = 0.05, far: float = 10.0,
           outputs: Sequence[str] = ("features", "alpha", "depth", "median_depth", "normal",
                                     "distortion"),
           backend: str = "auto", keep_tiles: Optional[Tensor] = None) -> RenderOutput:
    """Render N 2DGS splats into C cameras (viewmats world-to-camera, OpenCV axes).

    Differentiable w.r.t. means, quats, log_scales, opacity_logits and features ([N,D] shared by
    all cameras or [C,N,D] per camera). Pixel centers are at (i + 0.5, j + 0.5). Quaternions (w, x,
    y, z) need not be unit: every backend normalizes them.

    `keep_tiles` (bool [C, *tile_grid(width, height)]): only these TILE x TILE tiles are rendered;
    every image output is 0 on the others and no gradient comes from them (radii are unchanged).
    The cpu backend skips their work; the others render everything and mask it.
    """
    outputs = tuple(outputs)
    check_inputs(means, quats, log_scales, opacity_logits, features, viewmats, Ks, width, height,
                 near, far, outputs)
    grid = (viewmats.shape[0], *tile_grid(width, height))
    if keep_tiles is not None and (keep_tiles.dtype != torch.bool or tuple(keep_tiles.shape) != grid):
        raise FlightReconError(f"render: keep_tiles must be a bool tensor of shape {grid} (cameras, tile rows, "
                               f"tile columns of {TILE} px; render.tile_grid), got {keep_tiles.dtype} "
                               f"{tuple(keep_tiles.shape)}")
    name = resolve_backend(backend)
    if name != "cuda" and any(t.is_cuda for t in (means, quats, log_scales, opacity_logits, features)):
        raise FlightReconError(f"render: backend {name!r} needs CPU tensors, got CUDA ones "
                               "(use backend='cuda' or move them with .cpu())")
    if name == "reference":
        from flightrecon.render.backend_reference import render_reference_backend as fn
    elif name == "cpu":
        from flightrecon.render.backend_cpu import render_cpu as fn
    else:
        from flightrecon.render.backend_cuda import render_cuda as fn
    if name == "cpu":
        raw = fn(means, quats, log_scales, opacity_logits, features, viewmats, Ks, width, height,
                 near, far, outputs, keep_tiles)
    else:
        raw = fn(means, quats, log_scales, opacity_logits, features, viewmats, Ks, width, height,
                 near, far, outputs)
        if keep_tiles is not None:
            keep = tile_pixels(keep_tiles.to(means.device), width, height)
            raw = {k: (torch.where(keep, v, torch.zeros_like(v)) if k != "radii" and v is not None else v)
                   for k, v in raw.items()}
    out = RenderOutput(radii=raw["radii"])
    for key in OUTPUTS:
        if key in outputs and key != "normal_world":
            setattr(out, key, raw[key])
    if "normal_world" in outputs:
        # camera-to-world rotation is R^T: n_w = R^T n_c, i.e. row-vector n_c @ R
        out.normal_world = torch.einsum("chwi,cij->chwj", raw["normal"], viewmats[:, :3, :3])
    return out

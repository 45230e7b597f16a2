"""The map rendered at candidate camera poses, a chunk of cameras per rasterizer call: the one loop
every image-based view score runs (2D GauSS-MI with the depth prior, GauSS-MI, ActiveGS)."""

from __future__ import annotations

from typing import Callable, Iterator

import torch

from flightrecon.render import RenderOutput, render

CHUNK = 64  # cameras per call: bounds the [C,H,W,D] images of a call


def render_candidates(splats: dict[str, torch.Tensor], features: torch.Tensor | Callable[[torch.Tensor], torch.Tensor],
                      T_wc: torch.Tensor, K: torch.Tensor, width: int, height: int, *, near: float, far: float,
                      outputs: tuple[str, ...] = ("features",), backend: str = "auto",
                      chunk: int = CHUNK) -> Iterator[tuple[slice, RenderOutput]]:
    """(slice of the cameras, their render) for candidate poses T_wc [C,4,4] with intrinsics K [3,3].
    `features` is [N,D] for every camera, or a function of a chunk's poses [c,4,4] giving [c,N,D]."""
    for s in range(0, T_wc.shape[0], chunk):
        poses = T_wc[s:s + chunk]
        n = poses.shape[0]
        feats = features(poses) if callable(features) else features
        out = render(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"], feats,
                     torch.linalg.inv(poses), K[None].expand(n, 3, 3).contiguous(), width, height, near=near,
                     far=far, outputs=outputs, backend=backend)
        yield slice(s, s + n), out

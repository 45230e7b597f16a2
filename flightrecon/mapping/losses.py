"""The online 2DGS training loss (the paper's Eq. 6, masked as in 2DGS-SLAM).

L = (1 - w) L1(C) + w (1 - SSIM(C))                       over all pixels
  + lambda_D  mean |D - D_obs|                            over M
  + lambda_N  mean (1 - N . N_D)                          over M minus the image border
  + lambda_Dd mean distortion                             over all pixels
with M = pixels whose observed depth is valid and whose rendered alpha exceeds 0.95, D the expected
depth, N the rendered (camera-facing) normal and N_D the normal of the rendered depth surface.
The distortion image is the rasterizer's (normalized-depth squared form, see render/).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from flightrecon.mapping.image_metrics import ssim

ALPHA_MASK = 0.95


def normals_from_depth(depth: torch.Tensor, rays: torch.Tensor) -> torch.Tensor:
    """Camera-facing unit normals [..., H, W, 3] of the surface of z-depth [..., H, W, 1].

    `rays` [H, W, 3] are the pixel directions with z = 1; the border pixels get zero normals.
    """
    P = rays * depth
    dx = P[..., 1:-1, 2:, :] - P[..., 1:-1, :-2, :]
    dy = P[..., 2:, 1:-1, :] - P[..., :-2, 1:-1, :]
    n = F.normalize(torch.linalg.cross(dy, dx, dim=-1), dim=-1)
    return F.pad(n, (0, 0, 1, 1, 1, 1))


def training_loss(out, rgb: torch.Tensor, depth: torch.Tensor, rays: torch.Tensor, *, ssim_weight: float,
                  lambda_depth: float, lambda_normal: float, lambda_distortion: float) -> torch.Tensor:
    """Scalar loss of one rendered view `out` (RenderOutput, one camera) against rgb [H,W,3], depth [H,W,1]."""
    color = out.features[0]
    l1 = (color - rgb).abs().mean()
    loss = (1.0 - ssim_weight) * l1
    if ssim_weight > 0:
        loss = loss + ssim_weight * (1.0 - ssim(color, rgb))
    mask = (depth > 0) & (out.alpha[0].detach() > ALPHA_MASK)
    count = mask.sum().clamp_min(1)
    rendered_depth = out.depth[0]
    if lambda_depth > 0:
        loss = loss + lambda_depth * torch.where(mask, (rendered_depth - depth).abs(), 0.0).sum() / count
    if lambda_normal > 0:
        n_d = normals_from_depth(rendered_depth, rays)
        inner = mask.clone()
        inner[0, :] = inner[-1, :] = False
        inner[:, 0] = inner[:, -1] = False
        cos = (out.normal[0] * n_d).sum(-1, keepdim=True)
        loss = loss + lambda_normal * torch.where(inner, 1.0 - cos, 0.0).sum() / inner.sum().clamp_min(1)
    if lambda_distortion > 0:
        loss = loss + lambda_distortion * out.distortion[0].mean()
    return loss

"""The online 2DGS training loss (the paper's Eq. 5, masked as in 2DGS-SLAM).

L = (1 - w) L1(C) + w (1 - SSIM(C))                       over all pixels
  + lambda_D  mean |D - D_obs|                            over M
  + lambda_N  mean (1 - N . N_D)                          over M minus the image border
  + lambda_Dd mean distortion                             over all pixels
with M = pixels whose observed depth is valid and whose rendered alpha exceeds 0.95, D the expected
depth, N the rendered (camera-facing) normal and N_D the normal of the rendered depth surface.
The distortion image is the rasterizer's (normalized-depth squared form, see render/).

An iteration that renders only some tiles (`keep`, mapper.skip_tiles) trains on their pixels as a
window trains on its own: each term is averaged over the kept pixels. The dropped pixels take the
target's color (no error, no gradient; SSIM windows that reach into them see the target there) and
are out of M and of the distortion's mean.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from flightrecon import profiling
from flightrecon.mapping.image_metrics import SSIMTarget
from flightrecon.render import load_extension

ALPHA_MASK = 0.95


def normals_from_depth(depth: torch.Tensor, rays: torch.Tensor) -> torch.Tensor:
    """Camera-facing unit normals [..., H, W, 3] of the surface of z-depth [..., H, W, 1].

    `rays` [H, W, 3] are the pixel directions with z = 1; the border pixels get zero normals. The
    normal at a pixel is that of the cross product of the central differences of the back-projected
    points (vertical x horizontal). On the CPU one C++ pass each way (csrc/image_ops.cpp); the torch
    graph of the same formula cost the mapper ~6.6 ms of CPU per iteration at 320x240.
    """
    if depth.device.type == "cpu" and not rays.requires_grad:
        dtype = torch.promote_types(depth.dtype, rays.dtype)
        H, W = depth.shape[-3:-1]
        d = depth.to(dtype).reshape(-1, H, W).contiguous()
        return _DepthNormalsCPU.apply(d, rays.to(dtype).contiguous()).reshape(*depth.shape[:-1], 3)
    P = rays * depth
    dx = P[..., 1:-1, 2:, :] - P[..., 1:-1, :-2, :]
    dy = P[..., 2:, 1:-1, :] - P[..., :-2, 1:-1, :]
    n = F.normalize(torch.linalg.cross(dy, dx, dim=-1), dim=-1)
    return F.pad(n, (0, 0, 1, 1, 1, 1))


class _DepthNormalsCPU(torch.autograd.Function):
    """normals_from_depth of depth [B, H, W] on the CPU, differentiable in the depth."""

    @staticmethod
    def forward(ctx, depth, rays):
        with profiling.stage("depth normals"):
            ctx.save_for_backward(depth, rays)
            return load_extension().depth_normals(depth, rays)

    @staticmethod
    def backward(ctx, grad):
        with profiling.stage("depth normals backward"):
            depth, rays = ctx.saved_tensors
            return load_extension().depth_normals_backward(depth, rays, grad.contiguous()), None


@dataclass
class FrameTarget:
    """One observed frame prepared for repeated loss evaluation (masks and SSIM moments computed once)."""

    rgb: torch.Tensor  # [H, W, 3]
    depth: torch.Tensor  # [H, W, 1], 0 = invalid
    valid: torch.Tensor  # [H, W, 1] observed depth is valid
    valid_inner: torch.Tensor  # valid and not on the image border (where N_D is undefined)
    rays: torch.Tensor  # [H, W, 3] pixel directions, z = 1
    ssim: SSIMTarget | None


def frame_target(rgb: torch.Tensor, depth: torch.Tensor, rays: torch.Tensor, with_ssim: bool = True) -> FrameTarget:
    valid = depth > 0
    inner = valid.clone()
    inner[0, :] = inner[-1, :] = False
    inner[:, 0] = inner[:, -1] = False
    return FrameTarget(rgb, depth, valid, inner, rays, SSIMTarget(rgb) if with_ssim else None)


def training_loss(out, target: FrameTarget, *, ssim_weight: float, lambda_depth: float, lambda_normal: float,
                  lambda_distortion: float, keep: torch.Tensor | None = None) -> torch.Tensor:
    """Scalar loss of one rendered view `out` (RenderOutput, one camera) against `target`; with
    `keep` [H,W,1] (the pixels of the tiles rendered), over those pixels (module docstring)."""
    color = out.features[0]
    share = 1.0
    if keep is not None:
        color = torch.where(keep, color, target.rgb)
        share = max(float(keep.float().mean()), 1e-12)  # the full-image means below, over the kept pixels
    loss = (1.0 - ssim_weight) * (color - target.rgb).abs().mean() / share
    if ssim_weight > 0:
        loss = loss + ssim_weight * (1.0 - target.ssim(color)) / share
    opaque = out.alpha[0].detach() > ALPHA_MASK
    if keep is not None:
        opaque = opaque & keep
    rendered_depth = out.depth[0]
    if lambda_depth > 0:
        mask = target.valid & opaque
        err = torch.where(mask, (rendered_depth - target.depth).abs(), 0.0).sum()
        loss = loss + lambda_depth * err / mask.sum().clamp_min(1)
    if lambda_normal > 0:
        mask = target.valid_inner & opaque
        cos = (out.normal[0] * normals_from_depth(rendered_depth, target.rays)).sum(-1, keepdim=True)
        loss = loss + lambda_normal * torch.where(mask, 1.0 - cos, 0.0).sum() / mask.sum().clamp_min(1)
    if lambda_distortion > 0:
        distortion = out.distortion[0] if keep is None else torch.where(keep, out.distortion[0], 0.0)
        loss = loss + lambda_distortion * distortion.mean() / share
    return loss

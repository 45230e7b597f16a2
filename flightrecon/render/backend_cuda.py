"""The `cuda` backend: gsplat's `rasterization_2dgs` behind our API and conventions.

Known differences from the cpu/reference backends, read from gsplat 1.5.3's code
(rendering.py, cuda/csrc/RasterizeToPixels2DGSFwd.cu, cuda/_torch_impl_2dgs.py):
- Depth: gsplat blends each splat's CENTER depth (camera z of the mean, a per-splat constant
  appended as the last color channel), not the per-pixel ray-splat intersection depth. Expected
  and median depth therefore differ on tilted splats (exact for fronto-parallel ones); gsplat
  divides the expected depth by max(alpha, 1e-10) where we return 0 where alpha == 0.
- Distortion: gsplat accumulates raw center depths, 2 sum_{i>j} w_i w_j (d_i - d_j) style, not
  our squared normalized form; it is returned as-is and is not comparable across backends.
- Normals: gsplat returns the rendered normal in the WORLD frame; we rotate it to the camera frame
  for `normal` (same camera-facing sign rule: flip when n . p_c >= 0).
- Alpha is clamped at 0.999 (ours 0.99); a pixel stops when T(1 - alpha) <= 1e-4 (ours < 1e-4).
- No culling of splats whose 3.33-sigma disk reaches the camera plane, and the screen radius is
  ceil(3.33 * 1-sigma extent), which can crop the low-pass footprint of sub-pixel splats.
"""

from __future__ import annotations

import torch
from torch import Tensor


def render_cuda(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
                features: Tensor, viewmats: Tensor, Ks: Tensor, width: int, height: int,
                near: float, far: float, outputs: tuple[str, ...]) -> dict[str, Tensor]:
    from gsplat import rasterization_2dgs

    scales = torch.cat([torch.exp(log_scales), torch.ones_like(log_scales[:, :1])], -1)
    colors, alpha, normal_w, _, distort, median, meta = rasterization_2dgs(
        means, quats, scales, torch.sigmoid(opacity_logits), features, viewmats, Ks, width, height,
        near_plane=near, far_plane=far, render_mode="RGB+ED",
        distloss="distortion" in outputs)
    depth = torch.where(alpha > 0, colors[..., -1:], torch.zeros_like(alpha))
    normal = torch.einsum("cij,chwj->chwi", viewmats[:, :3, :3], normal_w)
    radii = meta["radii"]
    if radii.dim() == 3:
        radii = radii.amax(-1)
    return {"features": colors[..., :-1], "alpha": alpha, "depth": depth, "median_depth": median,
            "normal": normal, "distortion": distort, "radii": radii.int()}

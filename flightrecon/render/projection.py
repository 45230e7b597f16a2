"""2DGS splat geometry and its projection into cameras, in differentiable torch.

This is the readable statement of the projection that every backend uses: the C++ kernel
implements the same equations (and is tested against this module), the tests compare this module
with gsplat's own pure-torch 2DGS projection, and FisherRF's squared-gradient mode takes its
Jacobians from here.

Conventions (gsplat's and 2DGS's; docs/architecture.md, "Rasterizer"):
- A splat is (mean p, scaled tangents U = s_u t_u, V = s_v t_v, unit normal n = t_u x t_v).
- Its ray transform M = K [U_c | V_c | p_c] (camera frame) maps (u, v, 1) to pixel-homogeneous
  (x w, y w, w); its rows are T_u, T_v, T_w.
- means2d is the center of the image of the splat's unit ellipse (the 2DGS/gsplat "projected
  center" used by the low-pass filter); it equals the projected mean for a fronto-parallel splat.
- A splat is culled when its center depth is outside (near, far) or when its CUTOFF-sigma disk
  reaches the camera plane (its image would be unbounded): min_z of the disk =
  z_c - CUTOFF * |(U_c.z, V_c.z)| <= 0. gsplat does not cull the latter case.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
# A pixel can only receive alpha >= 1/255 where rho <= 2 ln(255) (opacity <= 1): 3.3290 sigma.
CUTOFF = 3.33
# Low-pass filter: rho2d = FILTER_INV_SQ * |pixel - means2d|^2 (sigma = sqrt(2)/2 px), so it can
# only reach sqrt(ln 255) = 2.3533 px from the center.
FILTER_INV_SQ = 2.0
FILTER_REACH = 2.36


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """[N,4] (w,x,y,z), not necessarily normalized -> [N,3,3] rotation matrices."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def splat_axes(quats: Tensor, log_scales: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """World-frame scaled tangents U, V and unit normal n, each [N,3]."""
    R = quat_to_rotmat(quats)
    s = torch.exp(log_scales)
    return R[..., 0] * s[..., :1], R[..., 1] * s[..., 1:2], R[..., 2]


class Projection(NamedTuple):
    ray_transforms: Tensor  # [C,N,3,3] rows T_u, T_v, T_w
    means2d: Tensor         # [C,N,2]
    depths: Tensor          # [C,N] camera z of the mean (the sort key)
    normals: Tensor         # [C,N,3] camera frame, flipped to face the camera
    radii: Tensor           # [C,N,2] int, gsplat's ceil(3.33 * 1-sigma extent); 0 if culled
    boxes: Tensor           # [C,N,4] float x0, y0, x1, y1 of every pixel the splat can reach
    visible: Tensor         # [C,N] bool: not culled and box meets the image


def _conic_box(M: Tensor) -> tuple[Tensor, Tensor]:
    """Center and half extents of the image of the unit circle under ray transform M [...,3,3]."""
    test = torch.tensor([1.0, 1.0, -1.0], dtype=M.dtype, device=M.device)
    Tu, Tv, Tw = M[..., 0, :], M[..., 1, :], M[..., 2, :]
    d = (Tw * Tw * test).sum(-1, keepdim=True)
    d = torch.where(d == 0, torch.full_like(d, -1e-30), d)
    center = torch.stack([(Tu * Tw * test).sum(-1), (Tv * Tw * test).sum(-1)], -1) / d
    sq = torch.stack([(Tu * Tu * test).sum(-1), (Tv * Tv * test).sum(-1)], -1) / d
    return center, torch.sqrt((center * center - sq).clamp_min(1e-4))


def project(means: Tensor, U: Tensor, V: Tensor, n: Tensor, viewmats: Tensor, Ks: Tensor,
            width: int, height: int, near: float, far: float) -> Projection:
    """Project N splats into C cameras (all [C,N,...] outputs)."""
    R, t = viewmats[:, :3, :3], viewmats[:, :3, 3]
    p_c = torch.einsum("cij,nj->cni", R, means) + t[:, None]
    U_c = torch.einsum("cij,nj->cni", R, U)
    V_c = torch.einsum("cij,nj->cni", R, V)
    n_c = torch.einsum("cij,nj->cni", R, n)
    sign = torch.where((n_c * p_c).sum(-1, keepdim=True) < 0, 1.0, -1.0).to(n_c.dtype)
    normals = n_c * sign
    cols = torch.stack([U_c, V_c, p_c], dim=-1)  # [C,N,3,3] columns U, V, p
    M = torch.einsum("cij,cnjk->cnik", Ks, cols)
    depths = p_c[..., 2]
    reach = CUTOFF * torch.sqrt(U_c[..., 2] ** 2 + V_c[..., 2] ** 2)
    valid = (depths > near) & (depths < far) & (depths - reach > 0)
    means2d, ext = _conic_box(M)
    radii = torch.ceil(CUTOFF * ext)
    # The CUTOFF-sigma ellipse: scale U, V columns (the first two columns of M) by CUTOFF.
    scale = torch.tensor([CUTOFF, CUTOFF, 1.0], dtype=M.dtype, device=M.device)
    c_center, c_ext = _conic_box(M * scale)
    lo = torch.minimum(c_center - c_ext, means2d - FILTER_REACH)
    hi = torch.maximum(c_center + c_ext, means2d + FILTER_REACH)
    boxes = torch.cat([lo, hi], -1)
    inside = (hi[..., 0] > 0) & (lo[..., 0] < width) & (hi[..., 1] > 0) & (lo[..., 1] < height)
    visible = valid & inside
    radii = torch.where(visible[..., None], radii, torch.zeros_like(radii)).int()
    return Projection(M, means2d, depths, normals, radii, boxes, visible)


def normalized_depth(z: Tensor, near: float, far: float) -> Tensor:
    """The distortion loss's NDC-like depth m(z) = far/(far-near) * (1 - near/z)."""
    return far / (far - near) * (1.0 - near / z)


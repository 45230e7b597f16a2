"""FisherRF's diagonal Hessian of a set of views, in the C++ kernel family.

H(theta) = sum over cameras and pixels of (d sum_c C_c(p) / d theta)^2 for position (means),
color, scale (log_scales) and opacity (logit), as in baselines.md (FisherRF). The kernel's Fisher
mode accumulates, per splat and camera, the outer product over pixels of each pixel's gradient
w.r.t. the splat's 11 screen-space quantities (ray transform rows and means2d), the squared opacity
gradient and the squared blend weight. A parameter's squared per-pixel contributions then follow
exactly as J^T G J with J the pixel-independent Jacobian of those 11 quantities (forward-mode
autograd of the torch projection, the same equations the kernel uses).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from flightrecon.render.api import check_inputs
from flightrecon.render.extension import load
from flightrecon.render.projection import project, splat_axes

NG = 11


class FisherDiag(NamedTuple):
    position: Tensor  # [N,3]
    color: Tensor     # [N,D]
    scale: Tensor     # [N,2] w.r.t. log_scales
    opacity: Tensor   # [N] w.r.t. opacity_logits


def _screen_jacobian(means, quats, log_scales, viewmats, Ks, width, height, near, far) -> Tensor:
    """[C,N,11,5]: d(T_u, T_v, T_w, means2d) / d(means xyz, log_scales uv) per splat."""

    def screen(m, ls):
        U, V, n = splat_axes(quats, ls)
        p = project(m, U, V, n, viewmats, Ks, width, height, near, far)
        return torch.cat([p.ray_transforms.flatten(-2), p.means2d], -1)

    cols = []
    for k in range(5):
        tm, tl = torch.zeros_like(means), torch.zeros_like(log_scales)
        (tm if k < 3 else tl)[:, k if k < 3 else k - 3] = 1.0
        cols.append(torch.func.jvp(screen, (means, log_scales), (tm, tl))[1])
    return torch.stack(cols, -1)


def render_fisher_diag(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
                       colors: Tensor, viewmats: Tensor, Ks: Tensor, width: int, height: int,
                       near: float = 0.05, far: float = 10.0) -> FisherDiag:
    """Diagonal Hessian summed over the C cameras (no gradients flow through it)."""
    check_inputs(means, quats, log_scales, opacity_logits, colors, viewmats, Ks, width, height,
                 near, far, ())
    with torch.no_grad():
        dt = means.dtype
        U, V, n = splat_axes(quats, log_scales)
        opac = torch.sigmoid(opacity_logits)
        feats = (colors if colors.dim() == 3 else colors[None]).to(dt).contiguous()
        cams = (viewmats.double().contiguous(), Ks.double().contiguous())
        geo = [t.to(dt).contiguous() for t in (means, U, V, n, opac)]
        ext = load()
        fwd = ext.forward(*geo, feats, *cams, width, height, near, far, False, False, False, True)
        grads = [torch.ones_like(fwd[0])] + [torch.zeros_like(t) for t in fwd[1:7]]
        kept = fwd[:6] + fwd[7:9]
        G_sym, o2, w2 = ext.backward(*geo, feats, *cams, width, height, near, far,
                                     False, False, False, kept, grads, True)
    C, N = G_sym.shape[:2]
    iu = torch.triu_indices(NG, NG)
    G = G_sym.new_zeros(C, N, NG, NG)
    G[:, :, iu[0], iu[1]] = G_sym
    G = G + G.transpose(-1, -2) - torch.diag_embed(torch.diagonal(G, dim1=-2, dim2=-1))
    with torch.no_grad():
        J = _screen_jacobian(means.detach().to(dt), quats.detach().to(dt),
                             log_scales.detach().to(dt), viewmats.to(dt), Ks.to(dt),
                             width, height, near, far)
        H = torch.einsum("cnak,cnab,cnbk->nk", J, G, J)
        s = opac * (1 - opac)
        D = feats.shape[-1]
    return FisherDiag(position=H[:, :3], color=w2.sum(0)[:, None].expand(N, D).clone(),
                      scale=H[:, 3:], opacity=o2.sum(0) * s * s)

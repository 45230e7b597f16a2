"""FisherRF's diagonal Hessian of a set of views, in the C++ kernel family.

H(theta) = sum over cameras and pixels of (d sum_c C_c(p) / d theta)^2 for position (means),
color, scale (log_scales) and opacity (logit), as in docs/baselines.md (FisherRF). The kernel's Fisher
mode accumulates, per splat and camera, the outer product over pixels of each pixel's gradient
w.r.t. the splat's 11 screen-space quantities (ray transform rows and means2d), the squared opacity
gradient and the squared blend weight. A parameter's squared per-pixel contributions then follow
exactly as J^T G J with J the pixel-independent Jacobian of those 11 quantities: written here in
closed form from `projection.project`'s equations (M = K [U_c | V_c | p_c]: a mean moves only the
p_c column, log s_u scales the U_c column, log s_v the V_c column; means2d is M's conic center),
and evaluated only for the (camera, splat) pairs the kernel saw cover a pixel, since G is zero for
all others. Tests hold it to autograd of `project`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from flightrecon.render.api import check_inputs
from flightrecon.render.extension import load
from flightrecon.render.backend_cpu import EVERY_TILE, splat_axes_cpu

NG = 11
_IU = torch.triu_indices(NG, NG)


class FisherDiag(NamedTuple):
    """Diagonal Hessian fields: [N,...] summed over cameras, or [C,N,...] per camera."""
    position: Tensor  # [N,3]
    color: Tensor     # [N,D]
    scale: Tensor     # [N,2] w.r.t. log_scales
    opacity: Tensor   # [N] w.r.t. opacity_logits


# Per parameter (means x, y, z, log s_u, log s_v): the column of M it moves (p_c, p_c, p_c, U_c, V_c).
_COLUMN = torch.tensor([2, 2, 2, 0, 1])
# ... and the indices of its nonzero Jacobian rows among the 11 (that column's 3 entries, means2d).
_ROWS = torch.stack([torch.tensor([j, 3 + j, 6 + j, 9, 10]) for j in _COLUMN.tolist()])
# Packed upper-triangle position of G[a, b] for the kernel's [.., 66] layout.
_PACKED = torch.zeros(NG, NG, dtype=torch.long)
_PACKED[_IU[0], _IU[1]] = torch.arange(_IU.shape[1])
_PACKED[_IU[1], _IU[0]] = torch.arange(_IU.shape[1])
_GATHER = _PACKED[_ROWS[:, :, None], _ROWS[:, None, :]].flatten()  # G[_ROWS[k], _ROWS[k]] per k
_DIAG = _PACKED.diagonal()


def jacobian_rows(means: Tensor, U: Tensor, V: Tensor, viewmats: Tensor, Ks: Tensor, cam: Tensor,
                  splat: Tensor) -> Tensor:
    """[P,5,5]: for each (camera, splat) pair (cam[P], splat[P]) and parameter k (means xyz,
    log_scales uv), the 5 nonzero entries of d(T_u, T_v, T_w, means2d) / d theta_k, at rows
    _ROWS[k]. U, V are the world-frame scaled tangents of `splat_axes`.

    M = K [U_c | V_c | p_c]: theta_k moves only column j = _COLUMN[k] of M, by c = K R e_k for a
    mean, by K U_c (K V_c) for log s_u (log s_v). means2d = (Tu.Tw, Tv.Tw) / Tw.Tw in the (1, 1, -1)
    metric (projection._conic_box), so its derivative follows from c and row j of (Tu, Tv, Tw)."""
    R, t = viewmats[:, :3, :3], viewmats[:, :3, 3]
    KR, Kt = (Ks @ R)[cam], (Ks @ t[..., None])[cam, :, 0]  # per camera, then per pair

    def apply(x: Tensor) -> Tensor:  # K R x for each pair's camera, x [P,3]
        return (KR * x[:, None, :]).sum(-1)

    M = torch.stack([apply(U[splat]), apply(V[splat]), apply(means[splat]) + Kt], -1)
    c = torch.cat([KR, M[:, :, :2]], -1).transpose(1, 2)  # [P,5,3]: d (column j of M) / d theta_k
    test = torch.tensor([1.0, 1.0, -1.0], dtype=M.dtype, device=M.device)
    Tu, Tv, Tw = M[:, 0], M[:, 1], M[:, 2]
    d = (Tw * Tw * test).sum(-1)
    degenerate = d == 0
    d = torch.where(degenerate, torch.full_like(d, -1e-30), d)
    s = test[_COLUMN]  # the metric's sign of column j
    tw, c2 = Tw[:, _COLUMN], c[..., 2]
    dd = torch.where(degenerate[:, None], 0.0, 2 * s * tw * c2)
    dm = [(s * (c[..., r] * tw + c2 * T[:, _COLUMN]) - ((T * Tw * test).sum(-1) / d)[:, None] * dd) / d[:, None]
          for r, T in ((0, Tu), (1, Tv))]
    return torch.cat([c, torch.stack(dm, -1)], -1)


def screen_jacobian(means: Tensor, U: Tensor, V: Tensor, viewmats: Tensor, Ks: Tensor, cam: Tensor,
                    splat: Tensor) -> Tensor:
    """[P,11,5]: the dense d(T_u, T_v, T_w, means2d) / d(means xyz, log_scales uv) of the pairs."""
    rows = jacobian_rows(means, U, V, viewmats, Ks, cam, splat)
    J = rows.new_zeros(len(rows), NG, 5)
    for k in range(5):
        J[:, _ROWS[k], k] = rows[:, k]
    return J


def render_fisher_diag(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
                       colors: Tensor, viewmats: Tensor, Ks: Tensor, width: int, height: int,
                       near: float = 0.05, far: float = 10.0, reduce: bool = True) -> FisherDiag:
    """Diagonal Hessian summed over the C cameras, or per camera ([C,N,...]) with reduce=False
    (no gradients flow through it)."""
    check_inputs(means, quats, log_scales, opacity_logits, colors, viewmats, Ks, width, height,
                 near, far, ())
    with torch.no_grad():
        dt = means.dtype
        U, V, n = splat_axes_cpu(quats, log_scales)  # the axes the cpu backend renders with
        opac = torch.sigmoid(opacity_logits)
        feats = (colors if colors.dim() == 3 else colors[None]).to(dt).contiguous()
        cams = (viewmats.double().contiguous(), Ks.double().contiguous())
        geo = [t.to(dt).contiguous() for t in (means, U, V, n, opac)]
        ext = load()
        fwd = ext.forward(*geo, feats, *cams, width, height, near, far, False, False, False, True, EVERY_TILE, None)
        grads = [torch.ones_like(fwd[0])] + [torch.zeros_like(t) for t in fwd[1:7]]
        kept = fwd[:6] + fwd[7:9]
        G_sym, o2, w2 = ext.backward(*geo, feats, *cams, width, height, near, far,
                                     False, False, False, kept, grads, True, EVERY_TILE, None)
        C, N = G_sym.shape[:2]
        # G's diagonal holds sums of squares: a pair with any nonzero entry has a positive diagonal.
        flat = G_sym.reshape(C * N, G_sym.shape[-1])
        pair = (flat.index_select(1, _DIAG.to(flat.device)).sum(-1) > 0).nonzero()[:, 0]
        cam, splat = pair // N, pair % N
        at = pair[:, None] * flat.shape[1] + _GATHER.to(flat.device)  # G[_ROWS[k], _ROWS[k]] of each pair
        Gk = flat.view(-1)[at].view(-1, 5, 5, 5)  # [P,k,a,b]
        v = jacobian_rows(geo[0], geo[1], geo[2], viewmats.to(dt), Ks.to(dt), cam, splat)
        Hp = torch.einsum("pka,pkab,pkb->pk", v, Gk, v)
        s = opac * (1 - opac)
        D = feats.shape[-1]
        if reduce:
            H = Hp.new_zeros(N, 5).index_add_(0, splat, Hp)
            return FisherDiag(position=H[:, :3], color=w2.sum(0)[:, None].expand(N, D).clone(),
                              scale=H[:, 3:], opacity=o2.sum(0) * s * s)
        H = Hp.new_zeros(C, N, 5)
        H[cam, splat] = Hp
        return FisherDiag(position=H[..., :3], color=w2[..., None].expand(C, N, D).clone(),
                          scale=H[..., 3:], opacity=o2 * s * s)

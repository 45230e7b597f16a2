"""Dense pure-torch 2DGS rasterizer: the per-pixel oracle for tests and the CPU speed peer.

Written from the equations, not from the kernel: every pixel's ray is intersected with every
splat's plane geometrically (ray-plane intersection, then local coordinates by projecting onto the
tangents), the low-pass center is the center of the image conic obtained by inverting the
homography, blending uses cumulative products, and the distortion uses the one-pass running sums of
docs/equations.md (Eq. 3). As in 2DGS, a pixel where the low-pass term wins takes the splat's center depth
(the ray-plane hit is meaningless there: tens of meters away for a grazing splat). No tiles and no Python loops over pixels or splats; pixels are processed in chunks so
that the [pixels, splats] intermediates fit in memory. Autograd gives its gradients.
"""

from __future__ import annotations

import torch
from torch import Tensor

from flightrecon.render.projection import (ALPHA_MAX, ALPHA_MIN, CUTOFF, FILTER_INV_SQ, T_MIN,
                                           normalized_depth, splat_axes)


def _conic_centers(K: Tensor, U_c: Tensor, V_c: Tensor, p_c: Tensor) -> Tensor:
    """Center of the image of each splat's unit ellipse: the conic H^-T diag(1,1,-1) H^-1."""
    H = torch.einsum("ij,njk->nik", K.double(), torch.stack([U_c, V_c, p_c], -1).double())
    Hi = torch.linalg.inv(H)
    Cq = Hi.transpose(-1, -2) @ torch.diag(H.new_tensor([1.0, 1.0, -1.0])) @ Hi
    center = -torch.linalg.solve(Cq[:, :2, :2], Cq[:, :2, 2:3])[..., 0]
    return center.to(p_c.dtype)


def _render_camera(means, U, V, n, opacity, feats, viewmat, K, width, height, near, far,
                   chunk):
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    p_c = means @ R.T + t
    U_c, V_c, n_c = U @ R.T, V @ R.T, n @ R.T
    z_c = p_c[:, 2]
    keep = (z_c > near) & (z_c < far) & (z_c - CUTOFF * torch.sqrt(U_c[:, 2] ** 2 + V_c[:, 2] ** 2) > 0)
    idx = torch.nonzero(keep)[:, 0]
    order = idx[torch.sort(z_c[idx], stable=True).indices]
    p_c, U_c, V_c, n_c = p_c[order], U_c[order], V_c[order], n_c[order]
    o, f = opacity[order], feats[order]
    facing = torch.where((n_c * p_c).sum(-1, keepdim=True) < 0, 1.0, -1.0).to(n_c.dtype) * n_c
    plane_n = torch.cross(U_c, V_c, dim=-1)
    center = _conic_centers(K, U_c, V_c, p_c) if len(order) else p_c[:, :2]
    D = f.shape[-1]
    ys, xs = torch.meshgrid(torch.arange(height, dtype=means.dtype) + 0.5,
                            torch.arange(width, dtype=means.dtype) + 0.5, indexing="ij")
    pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)
    rays = torch.cat([pix, torch.ones_like(pix[:, :1])], -1) @ torch.linalg.inv(K).T  # [P,3]
    outs = []
    step = max(1, chunk // max(1, len(order)))
    for s in range(0, pix.shape[0], step):
        d = rays[s:s + step, None, :]  # [P,1,3]
        denom = (d * plane_n).sum(-1)  # [P,N]
        ok = denom != 0
        tr = (p_c * plane_n).sum(-1) / torch.where(ok, denom, torch.ones_like(denom))
        X = tr[..., None] * d
        r = X - p_c
        u = (r * U_c).sum(-1) / (U_c * U_c).sum(-1)
        v = (r * V_c).sum(-1) / (V_c * V_c).sum(-1)
        rho3 = u * u + v * v
        rho2 = FILTER_INV_SQ * ((pix[s:s + step, None, :] - center) ** 2).sum(-1)
        # where the low-pass filter wins, the hit is not on the splat: use its center depth
        z = torch.where(rho3 <= rho2, X[..., 2], p_c[:, 2])
        ok = ok & (z >= near)
        a = torch.clamp_max(o * torch.exp(-0.5 * torch.minimum(rho3, rho2)), ALPHA_MAX)
        a = torch.where(ok & (a >= ALPHA_MIN), a, torch.zeros_like(a))
        T_incl = torch.cumprod(1 - a, dim=-1)
        T_excl = torch.cat([torch.ones_like(a[:, :1]), T_incl[:, :-1]], -1)
        blend = T_incl >= T_MIN
        w = torch.where(blend, a * T_excl, torch.zeros_like(a))
        zs = torch.where(ok, z, torch.ones_like(z))
        m = normalized_depth(zs, near, far)
        alpha = w.sum(-1, keepdim=True)
        feat = w @ f if D else w.new_zeros(w.shape[0], 0)
        normal = w @ facing
        zsum = (w * zs).sum(-1, keepdim=True)
        depth = torch.where(alpha > 0, zsum / torch.where(alpha > 0, alpha, torch.ones_like(alpha)),
                            torch.zeros_like(alpha))
        # One pass of running sums (A, M1, M2 over the splats in front): the distortion of
        # docs/equations.md (Eq. 3), sum_{i>j} w_i w_j (m_i - m_j)^2.
        A = torch.cumsum(w, -1) - w
        M1 = torch.cumsum(w * m, -1) - w * m
        M2 = torch.cumsum(w * m * m, -1) - w * m * m
        dist = (w * (m * m * A - 2 * m * M1 + M2)).sum(-1, keepdim=True)
        med_ok = blend & (a > 0) & (T_excl > 0.5)
        last = a.shape[1] - 1 - torch.flip(med_ok.int(), [-1]).argmax(-1) if a.shape[1] else None
        if last is None:
            median = torch.zeros_like(alpha)
        else:
            median = torch.where(med_ok.any(-1, keepdim=True),
                                 zs.gather(1, last[:, None]), torch.zeros_like(alpha))
        outs.append(torch.cat([feat, alpha, depth, median, normal, dist], -1))
    img = torch.cat(outs, 0).reshape(height, width, -1)
    return img, D


def render_reference(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
                     features: Tensor, viewmats: Tensor, Ks: Tensor, width: int, height: int,
                     near: float, far: float, chunk: int = 1 << 22) -> dict[str, Tensor]:
    """All outputs, dense, for C cameras: features, alpha, depth, median_depth, normal, distortion.

    `chunk` bounds the number of pixel-splat pairs held at once (memory, not results).
    """
    U, V, n = splat_axes(quats, log_scales)
    opacity = torch.sigmoid(opacity_logits)
    per_cam = features.dim() == 3
    imgs = []
    for c in range(viewmats.shape[0]):
        img, D = _render_camera(means, U, V, n, opacity, features[c] if per_cam else features,
                                viewmats[c], Ks[c], width, height, near, far, chunk)
        imgs.append(img)
    x = torch.stack(imgs, 0)
    names = [("features", D), ("alpha", 1), ("depth", 1), ("median_depth", 1), ("normal", 3),
             ("distortion", 1)]
    out, k = {}, 0
    for name, size in names:
        out[name] = x[..., k:k + size]
        k += size
    return out

"""The `cpu` backend: the C++ kernels (csrc/rasterize_*.cpp, one file per stage) as a torch autograd function.

The kernel consumes world-frame splat axes (mean, U = s_u t_u, V = s_v t_v, unit normal n): the
camera projection is linear in them, so the kernel's backward returns their gradients directly and
SplatAxesCPU carries them on to quats and log_scales (projection.splat_axes is its statement). The
kernel blends raw sums (alpha, sum w z, sum w m, sum w m^2); expected depth and distortion
(alpha * M2 - M1^2, which equals sum_{i>j} w_i w_j (m_i - m_j)^2) are formed here, so their
gradients come from autograd too.
"""

from __future__ import annotations

import torch
from torch import Tensor

from flightrecon import profiling
from flightrecon.render.extension import load


def _prep(t: Tensor, dtype: torch.dtype) -> Tensor:
    return t.to(dtype).contiguous()


EVERY_TILE = torch.empty(0, 0, dtype=torch.uint8)  # the kernels' keep_tiles: render every tile
CHUNK = 16384  # elements; below torch's parallel grain (32768), so one thread computes each chunk


class OpacityCPU(torch.autograd.Function):
    """sigmoid(logits) computed the same at any thread count.

    torch splits an elementwise op over more than 32768 elements among its threads, and each share
    runs its vector loop then a scalar tail whose sigmoid rounds differently: which splats get the
    scalar formula then depends on the thread count, and flights at 1 and 2 threads drifted apart
    once a view held more than 32768 splats. Fixed chunks below the grain put every element on the
    same path at any thread count; the backward s (1 - s) g is chunked alike."""

    @staticmethod
    def forward(ctx, logits):
        s = torch.cat([torch.sigmoid(c) for c in logits.split(CHUNK)]) if len(logits) else torch.sigmoid(logits)
        ctx.save_for_backward(s)
        return s

    @staticmethod
    def backward(ctx, grad):
        s, = ctx.saved_tensors
        if not len(s):
            return grad
        return torch.cat([g * ((1 - c) * c) for g, c in zip(grad.split(CHUNK), s.split(CHUNK))])


def opacity_cpu(logits: Tensor) -> Tensor:
    """Splat opacities from their logits, identical at any thread count (OpacityCPU)."""
    return OpacityCPU.apply(logits)


class SplatAxesCPU(torch.autograd.Function):
    """(quats [N,4] of any norm, log_scales [N,2]) -> world-frame U, V, n [N,3], in one C++ pass.

    Same values as projection.splat_axes; its torch graph is ~30 elementwise nodes, whose backward
    alone cost the mapper ~9 ms of a ~95 ms iteration at 100k splats."""

    @staticmethod
    def forward(ctx, quats, log_scales):
        with profiling.stage("splat axes"):
            q, s = quats.contiguous(), log_scales.to(quats.dtype).contiguous()
            ctx.save_for_backward(q, s)
            return tuple(load().splat_axes_forward(q, s))

    @staticmethod
    def backward(ctx, gU, gV, gn):
        with profiling.stage("splat axes backward"):
            q, s = ctx.saved_tensors
            grads = [g.contiguous() if g is not None else torch.zeros(q.shape[0], 3, dtype=q.dtype)
                     for g in (gU, gV, gn)]
            return tuple(load().splat_axes_backward(q, s, *grads))


def splat_axes_cpu(quats: Tensor, log_scales: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """World-frame scaled tangents U, V and unit normal n, each [N,3] (C++; differentiable)."""
    return SplatAxesCPU.apply(quats, log_scales)


@torch.no_grad()
def candidate_rows(means: Tensor, quats: Tensor, log_scales: Tensor, viewmat: Tensor, K: Tensor, width: int,
                   height: int, near: float, far: float) -> Tensor:
    """Increasing indices of every splat that the cpu backend could draw into one camera's image.

    The kernel's own first culling test (each splat's bounding sphere against the frustum widened by
    the low-pass reach, and its mean against the near plane) with a margin for float rounding, so
    the rows hold every splat with radii > 0; a non-pinhole K keeps every splat. Rendering only
    these rows (in this order) gives the full map's image exactly.
    """
    U, V, _ = splat_axes_cpu(quats, log_scales)
    dt = means.dtype
    return load().candidate_rows(_prep(means, dt), _prep(U, dt), _prep(V, dt), viewmat.detach().double(),
                                 K.detach().double(), width, height, float(near), float(far))


class RasterizeCPU(torch.autograd.Function):
    """(means, U, V, n, opacity, features[Cf,N,D]) -> raw per-pixel sums for C cameras."""

    @staticmethod
    def forward(ctx, means, U, V, n, opac, feats, viewmats, Ks, width, height, near, far,
                normal, depth, dist, track, keep_tiles):
        dt = means.dtype
        args = [_prep(t, dt) for t in (means, U, V, n, opac, feats)]
        cams = (viewmats.detach().double().contiguous(), Ks.detach().double().contiguous())
        ext = load()
        # a single camera's projection and bins, kept for the backward (which would redo them)
        ctx.cache = ext.RenderCache() if track and any(ctx.needs_input_grad[:6]) else None
        outs = ext.forward(*args, *cams, width, height, near, far, normal, depth, dist, track, keep_tiles, ctx.cache)
        profiling.add_kernel("forward", ext.last_stats)
        ctx.save_for_backward(*args, *cams, *outs[:9])
        ctx.meta = (width, height, near, far, normal, depth, dist)
        ctx.keep_tiles = keep_tiles
        ctx.mark_non_differentiable(*outs[7:])
        return tuple(outs)

    @staticmethod
    def backward(ctx, gF, gA, gN, gZ, gM, gM2, gMed, *_):
        saved = ctx.saved_tensors
        args, cams, fwd = saved[:6], saved[6:8], list(saved[8:])
        grads = [g.contiguous() if g is not None else torch.zeros_like(o)
                 for g, o in zip((gF, gA, gN, gZ, gM, gM2, gMed), fwd[:7])]
        kept = fwd[:6] + fwd[7:9]  # the kernel re-derives everything else; median is not needed
        g = load().backward(*args, *cams, *ctx.meta, kept, grads, False, ctx.keep_tiles, ctx.cache)
        profiling.add_kernel("backward", load().last_stats)
        ctx.cache = None  # free it now; a second backward (retain_graph) recomputes
        return (*g, None, None, None, None, None, None, None, None, None, None, None)


def render_cpu(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
               features: Tensor, viewmats: Tensor, Ks: Tensor, width: int, height: int,
               near: float, far: float, outputs: tuple[str, ...],
               keep_tiles: Tensor | None = None) -> dict[str, Tensor]:
    U, V, n = splat_axes_cpu(quats, log_scales)
    keep = EVERY_TILE if keep_tiles is None else keep_tiles.reshape(len(viewmats), -1).to(torch.uint8).contiguous()
    feats = features if features.dim() == 3 else features[None]
    want_normal = "normal" in outputs or "normal_world" in outputs
    want_depth = "depth" in outputs
    want_dist = "distortion" in outputs
    # the median depth and the per-pixel last/median splat ids cost per-pixel bookkeeping that only
    # the median_depth output and the backward need (view selection asks for features alone)
    track = "median_depth" in outputs or (torch.is_grad_enabled() and any(
        t.requires_grad for t in (means, quats, log_scales, opacity_logits, features, viewmats, Ks)))
    feat, alpha, normal, zsum, msum, m2sum, median, _, _, radii = RasterizeCPU.apply(
        means, U, V, n, opacity_cpu(opacity_logits), feats, viewmats, Ks, width, height,
        float(near), float(far), want_normal, want_depth, want_dist, track, keep)
    alpha = alpha[..., None]
    out = {"features": feat, "alpha": alpha, "radii": radii}
    if track:
        out["median_depth"] = median[..., None]
    if want_normal:
        out["normal"] = normal
    if want_depth:
        seen = alpha > 0
        out["depth"] = torch.where(seen, zsum[..., None] / torch.where(seen, alpha, torch.ones_like(alpha)),
                                   torch.zeros_like(alpha))
    if want_dist:
        out["distortion"] = alpha * m2sum[..., None] - msum[..., None] ** 2
    return out

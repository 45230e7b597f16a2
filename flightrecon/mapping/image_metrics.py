"""Image metrics shared by training losses and evaluation: PSNR (capped, metric_defs.PSNR_MAX_DB),
SSIM, masked depth L1.

SSIM follows Wang et al. with an 11-tap Gaussian window (sigma 1.5) evaluated only where the window
fits inside the image ("valid" convolution), which is exactly what scikit-image's
`structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)` averages; it
is differentiable, so the D-SSIM training term uses the same function.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

from flightrecon import profiling
from flightrecon.metric_defs import PSNR_MAX_DB
from flightrecon.render import load_extension

_C1 = 0.01**2
_C2 = 0.03**2


@functools.lru_cache(maxsize=4)
def _gauss_taps(sigma: float, radius: int, dtype: torch.dtype) -> torch.Tensor:
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    return (g / g.sum()).to(dtype)


def _blur(x: torch.Tensor, sigma: float, radius: int) -> torch.Tensor:
    """Gaussian filter of [K, H, W] planes, valid region only: [K, H-2r, W-2r].

    On the CPU without autograd, the extension's separable row filter (csrc/image_ops.cpp, several
    times faster than torch's depthwise convolution there); otherwise one grouped (depthwise)
    separable convolution over all planes."""
    k = x.shape[0]
    g = _gauss_taps(sigma, radius, x.dtype).to(x.device)
    if x.device.type == "cpu" and not (torch.is_grad_enabled() and x.requires_grad):
        return load_extension().blur_valid(x.contiguous(), g)
    x = F.conv2d(x[None], g.view(1, 1, 1, -1).expand(k, 1, 1, -1), groups=k)
    return F.conv2d(x, g.view(1, 1, -1, 1).expand(k, 1, -1, 1), groups=k)[0]


def _planes(img: torch.Tensor) -> torch.Tensor:
    """[..., H, W, C] -> [(... * C), H, W]."""
    H, W, C = img.shape[-3:]
    return img.reshape(-1, H, W, C).permute(0, 3, 1, 2).reshape(-1, H, W)


def _ssim_from_moments(mu_a, aa, ab, mu_b, var_b_c2):
    var_a = aa - mu_a * mu_a
    cov = ab - mu_a * mu_b
    num = (2 * mu_a * mu_b + _C1) * (2 * cov + _C2)
    return num / ((mu_a * mu_a + mu_b * mu_b + _C1) * (var_a + var_b_c2))


class _SSIMAgainst(torch.autograd.Function):
    """Mean SSIM of planes `a` against fixed target moments, with an analytic backward.

    The backward needs only the three per-pixel partials of SSIM (w.r.t. mu_a, E[a^2], E[ab]) filtered
    once more by the transposed blur (the same Gaussian on the zero-padded map): one 9-plane
    convolution instead of autograd's convolution backward plus a dozen elementwise backward nodes.
    """

    @staticmethod
    def forward(ctx, pa, b, mu_b, var_b_c2, sigma, radius):
        with profiling.stage("ssim"):
            mu_a, aa, ab = _blur(torch.cat([pa, pa * pa, pa * b]), sigma, radius).chunk(3)
            a1 = 2 * mu_a * mu_b + _C1
            a2 = 2 * (ab - mu_a * mu_b) + _C2
            b1 = mu_a * mu_a + mu_b * mu_b + _C1
            b2 = aa - mu_a * mu_a + var_b_c2
            inv = 1.0 / (b1 * b2)
            s = a1 * a2 * inv
            ctx.save_for_backward(pa, b, mu_a, mu_b, a1, a2, b1, b2, inv, s)
            ctx.meta = (sigma, radius)
            return s.mean()

    @staticmethod
    def backward(ctx, grad):
        with profiling.stage("ssim backward"):
            pa, b, mu_a, mu_b, a1, a2, b1, b2, inv, s = ctx.saved_tensors
            sigma, radius = ctx.meta
            g = grad / s.numel()
            d_mu = (2 * mu_b * (a2 - a1) * inv - 2 * mu_a * s * (1.0 / b1 - 1.0 / b2)) * g
            d_aa = -s / b2 * g
            d_ab = 2 * a1 * inv * g
            r = 2 * radius  # the transposed 'valid' filter is the 'full' one: pad by the kernel width - 1
            full = _blur(F.pad(torch.cat([d_mu, d_aa, d_ab]), (r, r, r, r)), sigma, radius)
            g_mu, g_aa, g_ab = full.chunk(3)
            return g_mu + 2 * pa * g_aa + b * g_ab, None, None, None, None, None


class SSIMTarget:
    """SSIM against a fixed image (a training target): its moments are filtered once, not per call."""

    def __init__(self, b: torch.Tensor, sigma: float = 1.5, radius: int = 5) -> None:
        self.sigma, self.radius = sigma, radius
        self.b = _planes(b)
        mu_b, bb = _blur(torch.cat([self.b, self.b * self.b]), sigma, radius).chunk(2)
        self.mu_b = mu_b
        self.var_b_c2 = bb - mu_b * mu_b + _C2

    def __call__(self, a: torch.Tensor) -> torch.Tensor:
        """Mean SSIM of image `a` (same shape as the target) against the target; differentiable in `a`."""
        return _SSIMAgainst.apply(_planes(a), self.b, self.mu_b, self.var_b_c2, self.sigma, self.radius)


def ssim_map(a: torch.Tensor, b: torch.Tensor, sigma: float = 1.5, radius: int = 5) -> torch.Tensor:
    """Per-pixel SSIM of [..., H, W, C] images where the window fits: [..., H-2r, W-2r, C]."""
    lead = a.shape[:-3]
    C = a.shape[-1]
    pa, pb = _planes(a), _planes(b)
    m = _blur(torch.cat([pa, pb, pa * pa, pb * pb, pa * pb]), sigma, radius)
    mu_a, mu_b, aa, bb, ab = m.chunk(5)
    s = _ssim_from_moments(mu_a, aa, ab, mu_b, bb - mu_b * mu_b + _C2)
    return s.reshape(*lead, C, *s.shape[-2:]).movedim(-3, -1)


def ssim(a: torch.Tensor, b: torch.Tensor, sigma: float = 1.5, radius: int = 5) -> torch.Tensor:
    """Mean SSIM over pixels and channels of [..., H, W, C] images (one value per leading index)."""
    return ssim_map(a, b, sigma, radius).flatten(-3).mean(-1)


def psnr(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """PSNR in dB of [..., H, W, C] images with data range 1 (`psnr_of_mse`)."""
    return psnr_of_mse((a - b).square().flatten(-3).mean(-1))


def psnr_of_mse(mse: torch.Tensor) -> torch.Tensor:
    """PSNR in dB of a mean squared error at data range 1, at most PSNR_MAX_DB (zero error is not
    infinitely good: see metric_defs)."""
    return 10.0 * torch.log10(1.0 / mse.clamp_min(10.0 ** (-PSNR_MAX_DB / 10.0)))


def depth_l1(depth: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Mean |depth - observed| over pixels where the observation is valid (> 0 and finite)."""
    valid = torch.isfinite(observed) & (observed > 0)
    diff = torch.where(valid, (depth - torch.nan_to_num(observed)).abs(), torch.zeros_like(depth))
    return diff.flatten(-3).sum(-1) / valid.flatten(-3).sum(-1).clamp_min(1)

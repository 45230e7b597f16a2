"""Image metrics shared by training losses and evaluation: PSNR, SSIM, masked depth L1.

SSIM follows Wang et al. with an 11-tap Gaussian window (sigma 1.5) evaluated only where the window
fits inside the image ("valid" convolution), which is exactly what scikit-image's
`structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)` averages; it
is differentiable, so the D-SSIM training term uses the same function.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

_C1 = 0.01**2
_C2 = 0.03**2


@functools.lru_cache(maxsize=4)
def _gauss_taps(sigma: float, radius: int, dtype: torch.dtype) -> torch.Tensor:
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    return (g / g.sum()).to(dtype)


def ssim_map(a: torch.Tensor, b: torch.Tensor, sigma: float = 1.5, radius: int = 5) -> torch.Tensor:
    """Per-pixel SSIM of images [..., H, W, C] in [0, 1]; output [..., H-2r, W-2r, C]."""
    lead = a.shape[:-3]
    H, W, C = a.shape[-3:]
    x = torch.stack([a, b, a * a, b * b, a * b]).reshape(-1, H, W, C).permute(0, 3, 1, 2)
    x = x.reshape(-1, 1, H, W)
    g = _gauss_taps(sigma, radius, a.dtype).to(a.device)
    x = F.conv2d(x, g.view(1, 1, 1, -1))
    x = F.conv2d(x, g.view(1, 1, -1, 1))
    x = x.reshape(5, -1, C, H - 2 * radius, W - 2 * radius).permute(0, 1, 3, 4, 2)
    mu_a, mu_b, aa, bb, ab = x
    var_a = aa - mu_a * mu_a
    var_b = bb - mu_b * mu_b
    cov = ab - mu_a * mu_b
    s = ((2 * mu_a * mu_b + _C1) * (2 * cov + _C2)) / ((mu_a * mu_a + mu_b * mu_b + _C1) * (var_a + var_b + _C2))
    return s.reshape(*lead, H - 2 * radius, W - 2 * radius, C)


def ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM over pixels and channels of [..., H, W, C] images (one value per leading index)."""
    return ssim_map(a, b).flatten(-3).mean(-1)


def psnr(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """PSNR in dB of [..., H, W, C] images with data range 1."""
    mse = (a - b).square().flatten(-3).mean(-1)
    return 10.0 * torch.log10(1.0 / mse)


def depth_l1(depth: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Mean |depth - observed| over pixels where the observation is valid (> 0 and finite)."""
    valid = torch.isfinite(observed) & (observed > 0)
    diff = torch.where(valid, (depth - torch.nan_to_num(observed)).abs(), torch.zeros_like(depth))
    return diff.flatten(-3).sum(-1) / valid.flatten(-3).sum(-1).clamp_min(1)

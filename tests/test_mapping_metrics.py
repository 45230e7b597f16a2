"""Image metrics against scikit-image (the independent oracle) and a direct numpy depth L1."""

import numpy as np
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from flightrecon.mapping.image_metrics import SSIMTarget, depth_l1, psnr, ssim


def _pair(seed: int, h: int = 48, w: int = 64) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.random((h, w, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    return a, b


def test_psnr_matches_skimage():
    a, b = _pair(0)
    ours = float(psnr(torch.from_numpy(a), torch.from_numpy(b)))
    assert abs(ours - peak_signal_noise_ratio(a, b, data_range=1.0)) < 1e-9


def test_ssim_matches_skimage_gaussian_window():
    for seed in range(3):
        a, b = _pair(seed)
        ref = structural_similarity(a, b, data_range=1.0, channel_axis=2, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False)
        ours = float(ssim(torch.from_numpy(a), torch.from_numpy(b)))
        assert abs(ours - ref) < 1e-9


def test_ssim_batched_matches_single_and_identity_is_one():
    a, b = _pair(3)
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    vals = ssim(torch.stack([ta, tb]), torch.stack([ta, ta]))
    assert vals.shape == (2,)
    assert abs(float(vals[0]) - 1.0) < 1e-12
    assert abs(float(vals[1]) - float(ssim(tb, ta))) < 1e-12


def test_depth_l1_ignores_invalid_observations():
    rng = np.random.default_rng(1)
    obs = rng.uniform(0.5, 3.0, (20, 30, 1))
    obs[:5] = 0.0
    obs[5:7] = np.nan
    pred = obs + rng.normal(0, 0.02, obs.shape)
    valid = np.isfinite(obs) & (obs > 0)
    expected = np.abs(pred - obs)[valid].mean()
    assert abs(float(depth_l1(torch.from_numpy(np.nan_to_num(pred)), torch.from_numpy(obs))) - expected) < 1e-12


def test_training_ssim_value_and_analytic_gradient():
    # The training term (fixed target, hand-written backward) against skimage's value and against
    # torch.autograd.gradcheck's finite differences in float64.
    a, b = _pair(4, h=20, w=24)
    ref = structural_similarity(a, b, data_range=1.0, channel_axis=2, gaussian_weights=True, sigma=1.5,
                                use_sample_covariance=False)
    target = SSIMTarget(torch.from_numpy(b))
    ta = torch.from_numpy(a).requires_grad_(True)
    assert abs(float(target(ta).detach()) - ref) < 1e-9
    assert torch.autograd.gradcheck(target, (ta,), eps=1e-6, atol=1e-8)


def test_cpu_row_filter_equals_the_depthwise_convolution():
    # Without autograd the CPU filter is the extension's; with it, torch's convolution: they agree.
    from flightrecon.mapping.image_metrics import _blur

    x = torch.rand(9, 37, 53, generator=torch.Generator().manual_seed(5))
    fast = _blur(x, 1.5, 5)
    conv = _blur(x.clone().requires_grad_(True), 1.5, 5).detach()
    assert fast.shape == conv.shape == (9, 27, 43)
    torch.testing.assert_close(fast, conv, rtol=1e-6, atol=1e-7)

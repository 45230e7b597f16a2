"""Image metrics against scikit-image (the independent oracle) and a direct numpy depth L1."""

import numpy as np
import pytest
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


def test_depth_normals_of_a_plane_and_against_the_torch_graph():
    # A tilted plane z = 2 + 0.3 x seen by a pinhole camera: every interior normal is the plane's
    # (facing the camera), the border is zero; the CPU kernel equals the torch graph (taken when the
    # rays require grad) in value and depth gradient, and passes gradcheck.
    from flightrecon.geometry import pixel_rays
    from flightrecon.mapping.losses import normals_from_depth

    H, W = 9, 12
    K = np.array([[10.0, 0, 6.0], [0, 10.0, 4.5], [0, 0, 1]])
    rays = torch.as_tensor(pixel_rays(W, H, K), dtype=torch.float64)
    depth = 2.0 / (1.0 - 0.3 * rays[..., :1])  # z = 2 + 0.3 x along each ray
    n = normals_from_depth(depth, rays)
    expected = torch.tensor([0.3, 0.0, -1.0], dtype=torch.float64) / np.sqrt(1.09)
    torch.testing.assert_close(n[1:-1, 1:-1], expected.expand(H - 2, W - 2, 3), rtol=0, atol=1e-12)
    assert not n[0].any() and not n[:, -1].any()

    g = torch.Generator().manual_seed(2)
    d = (depth + 0.05 * torch.rand(2, H, W, 1, generator=g, dtype=torch.float64)).requires_grad_(True)
    w = torch.randn(2, H, W, 3, generator=g, dtype=torch.float64)
    fast = normals_from_depth(d, rays)
    (gd_fast,) = torch.autograd.grad((fast * w).sum(), d)
    slow = normals_from_depth(d, rays.clone().requires_grad_(True))
    (gd_slow,) = torch.autograd.grad((slow * w).sum(), d)
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(gd_fast, gd_slow, rtol=1e-10, atol=1e-12)
    assert torch.autograd.gradcheck(lambda x: normals_from_depth(x, rays), (d[:1].detach().clone().requires_grad_(True),))


def _blur_float64(x: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """'valid' separable correlation of [K, H, W] planes in float64 (scipy), the filter's oracle."""
    from scipy.ndimage import correlate1d

    r = len(taps) // 2
    y = correlate1d(correlate1d(x.astype(np.float64), taps, axis=1, mode="constant"), taps, axis=2, mode="constant")
    return y[:, r:-r, r:-r]


@pytest.mark.parametrize("value", [0.0, 1e-40, 1e-20, 1e20, 3e38])
def test_ssim_filter_on_edge_values_equals_float64(value):
    # Planes of zero, subnormal, tiny, huge and near-float-max values, with a random pattern and
    # its negation mixed in: the float32 row filter equals the float64 filter to float rounding
    # (no flush to zero, no overflow: the taps sum to one). Among subnormals float32 rounds to an
    # absolute 1.4e-45, so 22 rounded products and sums may be off by 1.6e-44; flushing gives 5e-41.
    from flightrecon.mapping.image_metrics import _blur, _gauss_taps

    g = torch.Generator().manual_seed(9)
    pattern = torch.rand(3, 21, 26, generator=g)
    x = (value * torch.cat([pattern, -pattern, torch.ones(1, 21, 26)])).float()
    out = _blur(x, 1.5, 5)
    expect = _blur_float64(x.numpy(), _gauss_taps(1.5, 5, torch.float64).numpy())
    assert torch.isfinite(out).all()
    np.testing.assert_allclose(out.numpy(), expect, rtol=1e-6, atol=1.6e-44)


@pytest.mark.parametrize("scale", [0.0, 1e-40, 1e-20, 1e20])
def test_depth_normals_on_edge_depths(scale):
    # A tilted plane at zero, subnormal, tiny and huge depths: float32 normals and their depth
    # gradient are finite and equal the float64 torch graph's (F.normalize's semantics: a normal
    # whose unnormalized length is below 1e-12 is zero); huge depths keep the plane's exact normal.
    from flightrecon.geometry import pixel_rays
    from flightrecon.mapping.losses import normals_from_depth

    H, W = 9, 12
    K = np.array([[10.0, 0, 6.0], [0, 10.0, 4.5], [0, 0, 1]])
    rays64 = torch.as_tensor(pixel_rays(W, H, K), dtype=torch.float64)
    depth64 = scale * 2.0 / (1.0 - 0.3 * rays64[..., :1])
    d = depth64.float().requires_grad_(True)
    n = normals_from_depth(d, rays64.float())
    w = torch.randn(H, W, 3, generator=torch.Generator().manual_seed(3))
    (grad,) = torch.autograd.grad((n * w).sum(), d)
    d64 = d.detach().double().requires_grad_(True)
    n64 = normals_from_depth(d64, rays64.clone().requires_grad_(True))  # the torch graph
    (grad64,) = torch.autograd.grad((n64 * w.double()).sum(), d64)
    assert torch.isfinite(n).all() and torch.isfinite(grad).all()
    torch.testing.assert_close(n.double(), n64, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(grad.double(), grad64, rtol=1e-4, atol=1e-6 * float(grad64.abs().max()) + 1e-30)
    if scale >= 1e20:
        expected = torch.tensor([0.3, 0.0, -1.0], dtype=torch.float64) / np.sqrt(1.09)
        torch.testing.assert_close(n[1:-1, 1:-1].double(), expected.expand(H - 2, W - 2, 3), rtol=0, atol=1e-6)

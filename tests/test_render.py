"""2DGS rasterizer: C++ cpu backend against the dense reference, gsplat's projection, finite
differences, brute-force FisherRF, edge cases and batching."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from flightrecon.errors import DataError, FlightReconError
from flightrecon.render import FisherDiag, render, render_fisher_diag, tile_grid
from flightrecon.render.backend_cpu import candidate_rows, splat_axes_cpu
from flightrecon.render.fisher import screen_jacobian
from flightrecon.render.projection import CUTOFF, project, splat_axes
from flightrecon.render.reference import render_reference

ALL = ("features", "alpha", "depth", "median_depth", "normal", "normal_world", "distortion")
IMAGES = ("features", "alpha", "normal", "normal_world", "distortion")


def make_scene(n, seed=0, dtype=torch.float32, spread=0.4, depth=2.0, size=(0.03, 0.2)):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * spread + torch.tensor([0.0, 0.0, depth])
    quats = torch.randn(n, 4, generator=g)
    log_scales = torch.log(torch.rand(n, 2, generator=g) * (size[1] - size[0]) + size[0])
    opacity = torch.randn(n, generator=g) + 1.0
    feats = torch.rand(n, 3, generator=g)
    return [t.to(dtype) for t in (means, quats, log_scales, opacity, feats)]


def cameras(c, w, h, dtype=torch.float32, f=None):
    f = f or 0.9 * w
    vm = torch.eye(4).repeat(c, 1, 1)
    for k in range(c):
        ang = 0.15 * k
        vm[k, :3, :3] = torch.tensor([[1.0, 0, 0], [0, torch.cos(torch.tensor(ang)), -torch.sin(torch.tensor(ang))],
                                      [0, torch.sin(torch.tensor(ang)), torch.cos(torch.tensor(ang))]])
        vm[k, :3, 3] = torch.tensor([0.05 * k, -0.03 * k, 0.1 * k])
    K = torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]]).repeat(c, 1, 1)
    return vm.to(dtype), K.to(dtype)


def assert_agree(a, b, atol=1e-4, rtol_depth=1e-4):
    """Within 1e-4; depths relative too, since grazing low-pass hits can lie tens of meters away."""
    for k in ALL:
        x, y = getattr(a, k), getattr(b, k)
        assert torch.isfinite(y).all(), k
        tol = atol + (rtol_depth * x.abs() if k in ("depth", "median_depth") else 0)
        assert ((x - y).abs() <= tol).all(), (k, (x - y).abs().max().item())
    assert torch.equal(a.radii, b.radii)


def test_projection_matches_gsplat_torch_projection():
    from gsplat.cuda._torch_impl_2dgs import _fully_fused_projection_2dgs

    means, quats, ls, _, _ = make_scene(200, seed=3)
    vm, K = cameras(3, 64, 48)
    U, V, n = splat_axes(quats, ls)
    ours = project(means, U, V, n, vm, K, 64, 48, 0.05, 10.0)
    scales = torch.cat([ls.exp(), torch.ones(200, 1)], -1)
    radii, m2d, depths, M, normals = _fully_fused_projection_2dgs(means, quats, scales, vm, K, 64, 48, 0.05, 10.0)
    torch.testing.assert_close(ours.ray_transforms, M, rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(ours.depths, depths)
    torch.testing.assert_close(ours.normals, normals, rtol=1e-5, atol=1e-6)
    vis = ours.visible
    assert vis.sum() > 100
    torch.testing.assert_close(ours.means2d[vis], m2d[vis], rtol=1e-5, atol=1e-3)
    # Convention difference: we additionally cull splats whose 3.33-sigma disk reaches the camera
    # plane; everywhere else the radii are gsplat's ceil(3.33 * extent).
    assert torch.equal(ours.radii[vis], radii[vis])
    assert (radii[~vis].amax(-1) == 0).logical_or(~ours.visible[~vis]).all()


def test_cpu_forward_matches_dense_reference_per_pixel():
    scene = make_scene(150, seed=1)
    vm, K = cameras(2, 50, 37)  # not multiples of the 16-pixel tile
    a = render(*scene, vm, K, 50, 37, outputs=ALL, backend="reference")
    b = render(*scene, vm, K, 50, 37, outputs=ALL, backend="cpu")
    assert a.alpha.max() > 0.9 and (a.median_depth > 0).float().mean() > 0.3
    assert_agree(a, b)


@pytest.mark.parametrize("per_camera", [False, True])
def test_cpu_gradients_match_reference_autograd(per_camera):
    means, quats, ls, op, feats = make_scene(40, seed=2, dtype=torch.float64)
    vm, K = cameras(2, 33, 20, torch.float64)
    if per_camera:
        feats = torch.stack([feats, feats.flip(0)])
    grads = {}
    for be in ("reference", "cpu"):
        ps = [t.clone().requires_grad_(True) for t in (means, quats, ls, op, feats)]
        out = render(*ps, vm, K, 33, 20, outputs=ALL, backend=be)
        g = torch.Generator().manual_seed(7)
        loss = sum((getattr(out, k) * torch.randn(getattr(out, k).shape, generator=g, dtype=torch.float64)).sum()
                   for k in ALL)
        loss.backward()
        grads[be] = [p.grad for p in ps]
    for name, x, y in zip(("means", "quats", "log_scales", "opacity", "features"), *grads.values()):
        assert x.abs().max() > 0, name
        torch.testing.assert_close(y, x, rtol=1e-6, atol=1e-7 * x.abs().max().item(), msg=name)


def test_float32_blend_loops_agree_with_float64():
    """The float32 AVX2 loops (8-column groups from any column, 4x2 groups for boxes at most 4 px
    wide, which reach one row past the box) against the float64 generic loops, on many small splats
    at every tile position; the gradient tolerance is float32's own (the old code's figures too)."""
    scene = make_scene(600, seed=5, spread=0.5, size=(0.002, 0.05))
    vm, K = cameras(2, 70, 45)
    res = {}
    for dt in (torch.float64, torch.float32):
        ps = [t.to(dt).clone().requires_grad_(True) for t in scene]
        out = render(*ps, vm.to(dt), K.to(dt), 70, 45, outputs=ALL, backend="cpu")
        g = torch.Generator().manual_seed(3)
        loss = sum((getattr(out, k).double() * torch.randn(getattr(out, k).shape, generator=g,
                                                            dtype=torch.float64)).sum() for k in ALL)
        loss.backward()
        res[dt] = (out, [p.grad.double() for p in ps])
    assert_agree(res[torch.float64][0], res[torch.float32][0])
    for name, x, y in zip(("means", "quats", "log_scales", "opacity", "features"), res[torch.float64][1],
                          res[torch.float32][1]):
        torch.testing.assert_close(y, x, rtol=0, atol=5e-3 * x.abs().max().item(), msg=name)


def test_cpu_gradcheck_float64():
    means, quats, ls, op, feats = make_scene(4, seed=11, dtype=torch.float64, spread=0.1, size=(0.05, 0.1))
    vm, K = cameras(2, 8, 6, torch.float64, f=6.0)

    def fn(m, q, s, o, f):
        out = render(m, q, s, o, f, vm, K, 8, 6, outputs=ALL, backend="cpu")
        return tuple(getattr(out, k) for k in ALL)

    inputs = [t.clone().requires_grad_(True) for t in (means, quats, ls, op, feats)]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


def test_cpu_splat_axes_match_the_torch_statement():
    """The C++ axes equal projection.splat_axes (values and autograd gradients) for quaternions of
    any norm, a zero one included, and pass a float64 gradcheck."""
    _, quats, ls, _, _ = make_scene(257, seed=4, dtype=torch.float64)
    quats = quats * torch.linspace(0.01, 30.0, 257, dtype=torch.float64)[:, None]
    quats[0] = 0.0
    weights = [torch.randn(257, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(k)) for k in range(3)]
    grads = {}
    for name, fn in (("torch", splat_axes), ("cpu", splat_axes_cpu)):
        q, s = quats.clone().requires_grad_(True), ls.clone().requires_grad_(True)
        axes = fn(q, s)
        sum(((a * w).sum() for a, w in zip(axes, weights))).backward()
        grads[name] = [*(a.detach() for a in axes), q.grad, s.grad]
    for name, x, y in zip(("U", "V", "n", "quats", "log_scales"), grads["torch"], grads["cpu"]):
        assert torch.isfinite(y).all(), name
        torch.testing.assert_close(y, x, rtol=1e-12, atol=1e-12, msg=name)
    q32, s32 = quats.float(), ls.float()
    for x, y in zip(splat_axes(q32, s32), splat_axes_cpu(q32, s32)):
        torch.testing.assert_close(y, x, rtol=1e-6, atol=1e-6)
    inputs = [quats[1:9].clone().requires_grad_(True), ls[1:9].clone().requires_grad_(True)]
    assert torch.autograd.gradcheck(splat_axes_cpu, inputs, eps=1e-6, atol=1e-7)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_candidate_rows_hold_every_drawn_splat(dtype):
    """candidate_rows keeps every splat the camera draws (radii > 0), culls most of the others, and
    rendering only its rows gives the full map's outputs; a skewed K keeps all rows."""
    means, quats, ls, op, feats = make_scene(3000, seed=21, dtype=dtype, spread=2.5, depth=0.5, size=(0.01, 0.4))
    vm, K = cameras(3, 48, 40, dtype)
    for c in range(3):
        rows = candidate_rows(means, quats, ls, vm[c], K[c], 48, 40, 0.05, 10.0)
        full = render(means, quats, ls, op, feats, vm[c:c + 1], K[c:c + 1], 48, 40, outputs=ALL, backend="cpu")
        drawn = torch.nonzero(full.radii[0] > 0, as_tuple=True)[0]
        assert len(drawn) > 100 and len(rows) < 0.6 * len(means)
        assert bool(torch.isin(drawn, rows).all()) and bool((rows[1:] > rows[:-1]).all())
        sub = render(means[rows], quats[rows], ls[rows], op[rows], feats[rows], vm[c:c + 1], K[c:c + 1], 48, 40,
                     outputs=ALL, backend="cpu")
        assert torch.equal(sub.radii[0], full.radii[0][rows])
        for k in ALL:  # to rounding: torch's sigmoid rounds a tensor's scalar tail its own way
            torch.testing.assert_close(getattr(sub, k), getattr(full, k), rtol=1e-5, atol=1e-6, msg=k)
    skew = K[0].clone()
    skew[0, 1] = 0.5
    assert len(candidate_rows(means, quats, ls, vm[0], skew, 48, 40, 0.05, 10.0)) == len(means)


def test_feature_gradient_is_per_splat_pixel_sum_of_weights():
    """render/rendered_view.py's identity: d(sum_p v(p) F(p)) / d f_i = sum_p v(p) w_i(p), and rendered
    one-hot features give the weights w_i(p) themselves."""
    means, quats, ls, op, _ = make_scene(30, seed=4)
    vm, K = cameras(2, 40, 30)
    onehot = torch.eye(30)
    weights = render(means, quats, ls, op, onehot, vm, K, 40, 30, outputs=("features",), backend="cpu").features
    v = torch.rand(2, 30, 40, 1, generator=torch.Generator().manual_seed(0))
    g = torch.rand(2, 30, 1, requires_grad=True)
    out = render(means, quats, ls, op, g, vm, K, 40, 30, outputs=("features",), backend="cpu")
    (v * out.features).sum().backward()
    expected = (v * weights).sum(dim=(1, 2))  # [C, N]
    torch.testing.assert_close(g.grad[..., 0], expected, rtol=1e-5, atol=1e-6)
    # and the rendered scalar is the weight-sum of the per-splat scalars
    torch.testing.assert_close(out.features[..., 0], (weights * g.detach()[:, None, None, :, 0]).sum(-1),
                               rtol=1e-5, atol=1e-6)


def test_fisher_diag_matches_bruteforce_per_pixel_autograd():
    means, quats, ls, op, cols = make_scene(6, seed=2, dtype=torch.float64, spread=0.2, depth=1.5, size=(0.05, 0.2))
    vm, K = cameras(2, 8, 6, torch.float64, f=8.0)
    fd = render_fisher_diag(means, quats, ls, op, cols, vm, K, 8, 6)

    def image(m, s, o, c):
        return render_reference(m, quats, s, o, c, vm, K, 8, 6, 0.05, 10.0)["features"].sum(-1).reshape(-1)

    J = torch.autograd.functional.jacobian(image, (means, ls, op, cols))
    for name, got, j in zip(("position", "scale", "opacity", "color"),
                            (fd.position, fd.scale, fd.opacity, fd.color), J):
        want = (j ** 2).sum(0)
        assert want.abs().max() > 0, name
        torch.testing.assert_close(got, want, rtol=1e-8, atol=1e-10, msg=name)


def test_screen_jacobian_matches_autograd_of_the_projection():
    """The closed-form Jacobian of (ray transform, means2d) against reverse-mode autograd of `project`."""
    N, C = 5, 3
    means, quats, ls, _, _ = make_scene(N, seed=3, dtype=torch.float64, spread=0.3, depth=1.5)
    vm, K = cameras(C, 16, 12, torch.float64, f=14.0)

    def screen(m, s):
        U, V, n = splat_axes(quats, s)
        p = project(m, U, V, n, vm, K, 16, 12, 0.05, 10.0)
        return torch.cat([p.ray_transforms.flatten(-2), p.means2d], -1)  # [C,N,11]

    Jm, Js = torch.autograd.functional.jacobian(screen, (means, ls))  # [C,N,11,N,3], [C,N,11,N,2]
    want = torch.stack([torch.cat([Jm[:, i, :, i], Js[:, i, :, i]], -1) for i in range(N)], 1)
    U, V, _ = splat_axes(quats, ls)
    cam, splat = torch.arange(C).repeat_interleave(N), torch.arange(N).repeat(C)
    got = screen_jacobian(means, U, V, vm, K, cam, splat).reshape(C, N, 11, 5)
    assert want[..., 9:, :].abs().max() > 0.1  # the means2d rows take part
    torch.testing.assert_close(got, want, rtol=1e-9, atol=1e-9)


def test_fisher_diag_per_camera_equals_one_call_per_camera():
    means, quats, ls, op, cols = make_scene(60, seed=4, spread=0.4, depth=2.0)
    vm, K = cameras(3, 24, 18)
    per = render_fisher_diag(means, quats, ls, op, cols, vm, K, 24, 18, reduce=False)
    total = render_fisher_diag(means, quats, ls, op, cols, vm, K, 24, 18)
    for c in range(3):
        one = render_fisher_diag(means, quats, ls, op, cols, vm[c:c + 1], K[c:c + 1], 24, 18)
        for name, a, b in zip(FisherDiag._fields, per, one):
            torch.testing.assert_close(a[c], b, rtol=1e-6, atol=0, msg=name)
    for name, a, b in zip(FisherDiag._fields, per, total):
        assert b.abs().max() > 0, name
        torch.testing.assert_close(a.sum(0), b, rtol=1e-5, atol=1e-7 * float(b.abs().max()), msg=name)


EDGE_CASES = {
    "behind_camera": lambda s: s[0].__setitem__((slice(None), 2), -s[0][:, 2]),
    "crossing_near": lambda s: s[0].__setitem__((slice(None), 2), torch.linspace(0.0, 0.15, len(s[0]))),
    "huge": lambda s: s[2].fill_(2.0),
    "all_transparent": lambda s: s[3].fill_(-30.0),
    "edge_on": lambda s: s[1].copy_(torch.tensor([0.7071, 0.7071, 0.0, 0.0]).expand_as(s[1])),
    # float32 edge values: scales that underflow to subnormals, subnormal and huge colors, opacity
    # logits that saturate the sigmoid, unnormalized quaternions far from unit length
    "subnormal_scales": lambda s: s[2].fill_(-100.0),
    "zero_colors": lambda s: s[4].zero_(),
    "subnormal_colors": lambda s: s[4].fill_(1e-40),
    "huge_colors": lambda s: s[4].mul_(1e30),
    "saturated_opacity": lambda s: s[3].copy_(torch.where(torch.arange(len(s[3])) % 2 == 0, 1e20, -1e20)),
    "tiny_quats": lambda s: s[1].mul_(1e-30),
    "huge_quats": lambda s: s[1].mul_(1e30),
}


@pytest.mark.parametrize("case", sorted(EDGE_CASES))
def test_edge_cases_agree_and_stay_finite(case):
    scene = make_scene(40, seed=5)
    EDGE_CASES[case](scene)
    vm, K = cameras(1, 21, 17)
    ps = [t.clone().requires_grad_(True) for t in scene]
    b = render(*ps, vm, K, 21, 17, outputs=ALL, backend="cpu")
    a = render(*scene, vm, K, 21, 17, outputs=ALL, backend="reference")
    if case == "huge_colors":  # the blended features scale with the colors: compare them relative to it
        big = float(scene[4].abs().max())
        a, b = (dataclasses.replace(o, features=o.features / big) for o in (a, b))
    assert_agree(a, b)
    sum(getattr(b, k).sum() for k in ALL).backward()
    assert all(torch.isfinite(p.grad).all() for p in ps)


def test_zero_splats_and_single_pixel():
    empty = [torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 2), torch.zeros(0), torch.zeros(0, 3)]
    vm, K = cameras(2, 5, 4)
    out = render(*empty, vm, K, 5, 4, outputs=ALL, backend="cpu")
    assert out.features.shape == (2, 4, 5, 3) and out.radii.shape == (2, 0)
    assert all((getattr(out, k) == 0).all() for k in ALL)
    scene = make_scene(30, seed=6)
    vm1, K1 = cameras(2, 1, 1, f=2.0)
    a = render(*scene, vm1, K1, 1, 1, outputs=ALL, backend="reference")
    b = render(*scene, vm1, K1, 1, 1, outputs=ALL, backend="cpu")
    assert b.alpha.shape == (2, 1, 1, 1) and b.alpha.max() > 0
    assert_agree(a, b)


def test_batched_cameras_equal_single_calls_exactly():
    scene = make_scene(120, seed=8)
    vm, K = cameras(3, 45, 35)
    ps = [t.clone().requires_grad_(True) for t in scene]
    batched = render(*ps, vm, K, 45, 35, outputs=ALL, backend="cpu")
    sum(getattr(batched, k).sum() for k in ALL).backward()
    grads_batched = [p.grad.clone() for p in ps]
    grads_sum = [torch.zeros_like(p) for p in ps]
    for c in range(3):
        qs = [t.clone().requires_grad_(True) for t in scene]
        single = render(*qs, vm[c:c + 1], K[c:c + 1], 45, 35, outputs=ALL, backend="cpu")
        for k in ALL + ("radii",):
            assert torch.equal(getattr(single, k)[0], getattr(batched, k)[c]), k
        sum(getattr(single, k).sum() for k in ALL).backward()
        grads_sum = [g + q.grad for g, q in zip(grads_sum, qs)]
    # gradients: the same sums, only grouped differently (cameras summed before the chain rule)
    for gb, gs in zip(grads_batched, grads_sum):
        torch.testing.assert_close(gb, gs, rtol=1e-5, atol=1e-6 * gs.abs().max().item())


def test_culled_batch_equals_single_calls_exactly():
    """Cameras looking every way from inside a cloud of splats: a batch culls whole splat groups
    against each camera's frustum and orders splats spatially (a single camera projects every splat
    in id order), so splats behind, beside and across the near plane or the frustum sides, and
    splats of equal depth, must come out the same bit for bit."""
    n, c = 4000, 8
    scene = make_scene(n, seed=11)
    scene[0] = torch.randn(n, 3, generator=torch.Generator().manual_seed(12)) * 1.5
    scene[0][:400, 2] = 2.0  # equal depths in camera 0: the tie rule (lower id first) decides
    yaw = torch.arange(c) * (2 * torch.pi / c)
    vm = torch.eye(4).repeat(c, 1, 1)
    vm[:, 0, 0], vm[:, 0, 2], vm[:, 2, 0], vm[:, 2, 2] = yaw.cos(), yaw.sin(), -yaw.sin(), yaw.cos()
    vm[:, :3, 3] = torch.tensor([0.1, -0.2, 0.3])
    K = torch.tensor([[30.0, 0, 20], [0, 30.0, 15], [0, 0, 1]]).repeat(c, 1, 1)
    batched = render(*scene, vm, K, 40, 30, outputs=ALL, backend="cpu")
    assert (batched.radii == 0).float().mean() > 0.5 and batched.alpha.amax() > 0.9
    for k in range(c):
        single = render(*scene, vm[k:k + 1], K[k:k + 1], 40, 30, outputs=ALL, backend="cpu")
        for key in ALL + ("radii",):
            assert torch.equal(getattr(single, key)[0], getattr(batched, key)[k]), (k, key)


def test_deterministic_across_runs():
    scene = make_scene(300, seed=9)
    vm, K = cameras(2, 64, 48)
    results = []
    for _ in range(2):
        ps = [t.clone().requires_grad_(True) for t in scene]
        out = render(*ps, vm, K, 64, 48, outputs=ALL, backend="cpu")
        sum(getattr(out, k).sum() for k in ALL).backward()
        results.append([getattr(out, k) for k in ALL] + [p.grad for p in ps])
    assert all(torch.equal(x, y) for x, y in zip(*results))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_backward_reuses_the_forward_projection_exactly(dtype):
    """A single camera's backward takes the projection and bins its forward kept (it bins nothing
    itself); a second backward over the same graph has them no more and recomputes them: the
    gradients must agree bit for bit."""
    from flightrecon.render.extension import load

    scene = make_scene(500, seed=13, dtype=dtype)
    scene[0][:50, 2] = torch.linspace(0.0, 0.2, 50, dtype=dtype)  # some across the near plane
    vm, K = cameras(1, 70, 50, dtype)
    ps = [t.clone().requires_grad_(True) for t in scene]
    out = render(*ps, vm, K, 70, 50, outputs=ALL, backend="cpu")
    loss = sum((getattr(out, k) * torch.linspace(0.5, 1.5, getattr(out, k).numel(), dtype=dtype)
                .view_as(getattr(out, k))).sum() for k in ALL)
    grads = []
    for binned in (False, True):
        for p in ps:
            p.grad = None
        loss.backward(retain_graph=True)
        stats = load().last_stats()
        assert (stats["bin_s"] > 0) == binned and stats["isects"] > 0
        grads.append([p.grad for p in ps])
    assert all(torch.equal(a, b) for a, b in zip(*grads))


def test_bad_inputs_give_clear_errors():
    scene = make_scene(5)
    vm, K = cameras(1, 8, 8)
    bad = [t.clone() for t in scene]
    bad[0][2, 1] = float("nan")
    with pytest.raises(DataError, match="means"):
        render(*bad, vm, K, 8, 8)
    bad = [t.clone() for t in scene]
    bad[1][0, 0] = float("-inf")
    with pytest.raises(DataError, match="quats"):
        render(*bad, vm, K, 8, 8)
    huge = scene[4].clone()
    huge[:2] = 3e38  # finite, though their sum overflows: not an error
    render(*scene[:4], huge, vm, K, 8, 8)
    with pytest.raises(FlightReconError, match="quats"):
        render(scene[0], scene[1][:, :3], *scene[2:], vm, K, 8, 8)
    with pytest.raises(FlightReconError, match="backend"):
        render(*scene, vm, K, 8, 8, backend="metal")
    with pytest.raises(FlightReconError, match="near"):
        render(*scene, vm, K, 8, 8, near=1.0, far=0.5)


def test_cutoff_covers_every_contributing_pixel():
    """CUTOFF must exceed sqrt(2 ln 255): the Mahalanobis reach of alpha >= 1/255."""
    assert CUTOFF >= (2 * torch.log(torch.tensor(255.0))).sqrt().item()


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA device (gsplat backend)")
def test_cuda_backend_agrees_on_fronto_parallel_splats():
    # gsplat blends center depths, so compare on fronto-parallel splats where they coincide.
    means, quats, ls, op, feats = make_scene(200, seed=12)
    quats = torch.tensor([1.0, 0, 0, 0]).repeat(200, 1)
    vm, K = cameras(2, 64, 48)
    a = render(means, quats, ls, op, feats, vm, K, 64, 48, outputs=ALL, backend="cpu")
    b = render(*[t.cuda() for t in (means, quats, ls, op, feats, vm, K)], 64, 48, outputs=ALL, backend="cuda")
    for k in ("features", "alpha", "depth", "normal", "normal_world"):
        torch.testing.assert_close(getattr(b, k).cpu(), getattr(a, k), atol=5e-3, rtol=1e-3, msg=k)


def test_backward_skips_only_groups_that_blend_nothing():
    """The forward records, per splat and tile, the pixel groups in which it blended; the backward then
    evaluates only those. On a dense, opaque scene (most pixels terminate early, big splats cover
    groups they never reach) it must give bit for bit what the backward that evaluates every group
    gives: that of a second backward, which no longer has the forward's record."""
    from flightrecon.render.extension import load

    scene = make_scene(4000, seed=21, spread=0.6, size=(0.05, 0.4))
    scene[3] = scene[3] + 3.0  # opaque: pixels terminate after a few splats
    vm, K = cameras(1, 96, 80)
    ps = [t.clone().requires_grad_(True) for t in scene]
    out = render(*ps, vm, K, 96, 80, outputs=ALL, backend="cpu")
    evals, blends = load().last_stats()["evals"], load().last_stats()["blends"]
    assert evals > 1.5 * blends  # groups that blend nothing exist, so the record skips some
    loss = sum((getattr(out, k) * torch.linspace(-1.0, 2.0, getattr(out, k).numel()).view_as(getattr(out, k)))
               .sum() for k in ALL)
    grads = []
    for _ in range(2):
        for p in ps:
            p.grad = None
        loss.backward(retain_graph=True)
        grads.append([p.grad.clone() for p in ps])
    assert all(torch.equal(a, b) for a, b in zip(*grads))


def test_a_view_of_more_splats_than_torchs_parallel_grain_renders_and_trains_alike_at_any_thread_count():
    """33,003 splats: torch splits an elementwise op over more than 32,768 elements among its threads,
    and at 2 threads torch.sigmoid rounds the scalar tail of the first share unlike at 1 (element
    16,485 of these logits on an AVX-512 host, where this test fails with torch.sigmoid). The image and every gradient at 2 threads equal those at 1 bit for bit, with the splats around
    that index in front of the rest; the opacities are sigmoid's to within an ulp of float64's, edge
    logits included."""
    from flightrecon.render.backend_cpu import opacity_cpu

    g = torch.Generator().manual_seed(3)
    n = 33_003
    logits = torch.randn(n, generator=g) * 3  # drawn first: element 16,485 is one that rounds apart
    means = torch.rand(n, 3, generator=g) * torch.tensor([2.0, 1.5, 1.0]) + torch.tensor([-1.0, -0.75, 1.5])
    means[16_400:16_600, 2] = 1.0  # nothing hides them
    quats = torch.randn(n, 4, generator=g)
    log_scales = torch.log(torch.rand(n, 2, generator=g) * 0.02 + 0.005)
    log_scales[16_400:16_600] = math.log(0.05)  # and they span pixels
    logits[:6] = torch.tensor([0.0, -0.0, 88.0, -88.0, 1e-8, -200.0])
    colors = torch.rand(n, 3, generator=g)
    viewmat, K = torch.eye(4)[None], torch.tensor([[[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]]])
    expected = torch.sigmoid(logits.double())
    assert torch.allclose(opacity_cpu(logits).double(), expected, rtol=2 ** -23, atol=1e-45)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = opacity_cpu(logits)
        torch.set_num_threads(2)
        assert torch.equal(opacity_cpu(logits), one)
    finally:
        torch.set_num_threads(before)

    def run(threads: int):
        torch.set_num_threads(threads)
        leaves = [t.clone().requires_grad_(True) for t in (means, quats, log_scales, logits, colors)]
        out = render(*leaves, viewmat, K, 64, 48, near=0.05, far=10.0, backend="cpu",
                     outputs=("features", "alpha", "depth", "normal", "distortion"))
        (out.features.square().sum() + out.depth.sum() + out.normal.sum() + out.distortion.sum()).backward()
        return [out.features, out.alpha, out.depth, out.normal] + [t.grad for t in leaves]

    before = torch.get_num_threads()
    try:
        one, two = run(1), run(2)
    finally:
        torch.set_num_threads(before)
    for a, b in zip(one, two):
        assert torch.equal(a, b)


def _keep_every_other_tile(c, w, h):
    rows, cols = tile_grid(w, h)
    keep = (torch.arange(rows)[:, None] + torch.arange(cols)[None]) % 2 == 0
    keep = keep[None].repeat(c, 1, 1)
    keep[-1, 0, 0] = False  # the cameras differ
    return keep


def test_dropped_tiles_render_nothing_and_kept_tiles_exactly_the_full_image():
    scene = make_scene(300, seed=4)
    vm, K = cameras(2, 50, 37)  # the last tile row and column are partial
    keep = _keep_every_other_tile(2, 50, 37)
    full = render(*scene, vm, K, 50, 37, outputs=ALL, backend="cpu")
    part = render(*scene, vm, K, 50, 37, outputs=ALL, backend="cpu", keep_tiles=keep)
    pixels = keep.repeat_interleave(16, 1).repeat_interleave(16, 2)[:, :37, :50]
    assert full.alpha[pixels].max() > 0.9 and full.alpha[~pixels].max() > 0.9  # both sets hold surface
    for k in ALL:
        x, y = getattr(full, k), getattr(part, k)
        assert torch.equal(y[pixels], x[pixels]), k  # the same splats in the same order: bit for bit
        assert (y[~pixels] == 0).all(), k
    assert torch.equal(part.radii, full.radii)
    ref = render(*scene, vm, K, 50, 37, outputs=ALL, backend="reference", keep_tiles=keep)
    assert_agree(ref, part)


def test_dropped_tiles_pass_no_gradient_and_kept_ones_the_references():
    means, quats, ls, op, feats = make_scene(60, seed=5, dtype=torch.float64)
    vm, K = cameras(2, 40, 20, torch.float64)
    keep = _keep_every_other_tile(2, 40, 20)
    grads = {}
    pixels = keep.repeat_interleave(16, 1).repeat_interleave(16, 2)[:, :20, :40, None]
    # oracle: a full render whose loss leaves the dropped pixels out; the cpu loss keeps them in
    for be, kt, weight in (("reference", None, pixels), ("cpu", keep, torch.ones_like(pixels))):
        ps = [t.clone().requires_grad_(True) for t in (means, quats, ls, op, feats)]
        out = render(*ps, vm, K, 40, 20, outputs=ALL, backend=be, keep_tiles=kt)
        g = torch.Generator().manual_seed(8)
        loss = sum((torch.where(weight, getattr(out, k), 0.0)
                    * torch.randn(getattr(out, k).shape, generator=g, dtype=torch.float64)).sum() for k in ALL)
        loss.backward()
        grads[be] = [p.grad for p in ps]
    for name, x, y in zip(("means", "quats", "log_scales", "opacity", "features"), *grads.values()):
        assert x.abs().max() > 0, name
        torch.testing.assert_close(y, x, rtol=1e-6, atol=1e-7 * x.abs().max().item(), msg=name)


def test_keep_tiles_of_the_wrong_shape_or_type_is_refused_with_the_grid_it_needs():
    scene = make_scene(10)
    vm, K = cameras(1, 40, 20)
    with pytest.raises(FlightReconError, match=r"keep_tiles must be a bool tensor of shape \(1, 2, 3\)"):
        render(*scene, vm, K, 40, 20, keep_tiles=torch.ones(1, 3, 3, dtype=torch.bool))
    with pytest.raises(FlightReconError, match="keep_tiles"):
        render(*scene, vm, K, 40, 20, keep_tiles=torch.ones(1, 2, 3))

"""Map store growth and compaction, and the sparse Adam against torch's own Adam."""

import numpy as np
import pytest
import torch

from flightrecon.mapping.optimizer import SparseAdam
from flightrecon.mapping.store import PARAM_SHAPES, GaussianMap


def _params(m: int, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {name: torch.randn((m, *shape), generator=g) for name, shape in PARAM_SHAPES.items()}


def test_append_grows_by_doubling_and_keeps_rows():
    gmap = GaussianMap(capacity=4)
    a, b = _params(3, 0), _params(6, 1)
    gmap.append(frame=0, **a)
    assert gmap.capacity == 4
    gmap.append(frame=1, **b)
    assert len(gmap) == 9 and gmap.capacity == 16
    for name in PARAM_SHAPES:
        assert torch.equal(gmap[name], torch.cat([a[name], b[name]]))
    assert gmap["frame_created"].tolist() == [0] * 3 + [1] * 6


def test_keep_compacts_every_column_including_optimizer_state():
    gmap = GaussianMap(capacity=2)
    adam = SparseAdam(gmap, {"means": 0.1})
    gmap.append(frame=0, **_params(5, 2))
    gmap["adam_m.means"][:] = torch.arange(5.0)[:, None]
    gmap.add_column("reliability", (2,), torch.float32)
    gmap["reliability"][:, 0] = torch.arange(5.0)
    means = gmap["means"].clone()
    mask = torch.tensor([True, False, True, False, True])
    gmap.keep(mask)
    assert len(gmap) == 3
    assert torch.equal(gmap["means"], means[mask])
    assert gmap["adam_m.means"][:, 0].tolist() == [0.0, 2.0, 4.0]
    assert gmap["reliability"][:, 0].tolist() == [0.0, 2.0, 4.0]
    assert adam.gmap is gmap


def test_sparse_adam_matches_torch_adam_on_visible_rows_and_freezes_the_rest():
    gmap = GaussianMap()
    lrs = {"means": 1e-2, "quats": 1e-3, "log_scales": 5e-3, "opacity_logits": 5e-2, "colors": 2.5e-3}
    adam = SparseAdam(gmap, lrs)
    init = _params(10, 3)
    gmap.append(frame=0, **init)
    visible = torch.arange(0, 10, 2)
    ref = {k: v[visible].clone().requires_grad_(True) for k, v in init.items()}
    ref_opt = torch.optim.Adam([{"params": [ref[k]], "lr": lr} for k, lr in lrs.items()], eps=1e-15)
    targets = _params(10, 4)
    for _ in range(5):
        leaves = adam.leaves()
        sum(((leaves[k] - targets[k]) ** 2).sum() for k in leaves).backward()
        adam.step(leaves, visible)
        ref_opt.zero_grad()
        sum(((ref[k] - targets[k][visible]) ** 2).sum() for k in ref).backward()
        ref_opt.step()
    hidden = torch.arange(1, 10, 2)
    for k in PARAM_SHAPES:
        np.testing.assert_allclose(gmap[k][visible].numpy(), ref[k].detach().numpy(), rtol=1e-5, atol=1e-6)
        assert torch.equal(gmap[k][hidden], init[k][hidden])
    assert gmap["adam_step"][visible].tolist() == [5] * 5
    assert gmap["adam_step"][hidden].tolist() == [0] * 5


def _adam_reference(p, g, m, v, t, lr, b1=0.9, b2=0.999, eps=1e-15):
    """Adam on rows, in float64, each row with its own step count `t` (already incremented)."""
    p, g, m, v = (a.double() for a in (p, g, m, v))
    t = t.double().view((-1,) + (1,) * (p.dim() - 1))
    m = b1 * m + (1 - b1) * g
    v = b2 * v + (1 - b2) * g * g
    m_hat, v_hat = m / (1 - b1 ** t), v / (1 - b2 ** t)
    return p - lr * m_hat / (v_hat.sqrt() + eps), m, v


@pytest.mark.parametrize("path", ["kernel", "torch"])
@pytest.mark.parametrize("gathered", [False, True])
def test_sparse_adam_step_equals_a_per_splat_adam(path, gathered):
    """Several steps on a changing visible set, from unequal step counts and nonzero moments, with a
    frozen parameter (lr 0), a splat with zero gradient and moments, and (gathered) leaves that are a
    copy of some map rows: the C++ step and the torch one (maps off the CPU) equal a plain per-splat
    Adam; rows not visible keep their moments, steps and values."""
    N = 300
    gmap = GaussianMap()
    lrs = {"means": 1e-2, "quats": 1e-3, "log_scales": 0.0, "opacity_logits": 5e-2, "colors": 2.5e-3}
    adam = SparseAdam(gmap, lrs)
    gmap.append(frame=0, **_params(N, 5))
    gen = torch.Generator().manual_seed(6)
    gmap["adam_step"][:] = torch.randint(0, 60, (N,), generator=gen, dtype=torch.int32)
    for name, shape in PARAM_SHAPES.items():
        gmap[f"adam_m.{name}"][:] = torch.randn((N, *shape), generator=gen) * 0.1
        gmap[f"adam_v.{name}"][:] = torch.rand((N, *shape), generator=gen) * 0.01
    rows = torch.arange(7, N - 20, 2) if gathered else None
    n_local = N if rows is None else len(rows)
    at = torch.arange(N) if rows is None else rows  # map row of each leaf row
    zero = 3  # a leaf row with zero gradient and zero moments: its update must be exactly zero
    for name in PARAM_SHAPES:
        gmap[f"adam_m.{name}"][at[zero]] = 0.0
        gmap[f"adam_v.{name}"][at[zero]] = 0.0
    expect = {k: gmap[k].clone() for k in gmap._cols}
    before = {k: v.clone() for k, v in expect.items()}
    seen = []
    leaves = adam.leaves() if rows is None else adam.gather(rows)
    for _ in range(4):
        visible = torch.nonzero(torch.rand(n_local, generator=gen) < 0.7, as_tuple=True)[0]
        visible = torch.unique(torch.cat([visible, torch.tensor([zero])]))
        for name, p in leaves.items():
            p.grad = torch.randn(p.shape, generator=gen)
            p.grad[zero] = 0.0
        rv = at[visible]
        seen.append(rv)
        expect["adam_step"][rv] += 1
        for name, p in leaves.items():
            if lrs[name] > 0:
                new_p, new_m, new_v = _adam_reference(
                    expect[name][rv], p.grad[visible], expect[f"adam_m.{name}"][rv],
                    expect[f"adam_v.{name}"][rv], expect["adam_step"][rv], lrs[name])
                expect[name][rv] = new_p.float()
                expect[f"adam_m.{name}"][rv] = new_m.float()
                expect[f"adam_v.{name}"][rv] = new_v.float()
        if path == "kernel":
            adam.step(leaves, visible, rows)
        else:  # the update maps off the CPU get, here on CPU tensors
            adam._step_torch({k: p for k, p in leaves.items() if lrs[k] > 0}, visible, rows)
            for p in leaves.values():
                p.grad = None
        assert all(p.grad is None for p in leaves.values())
    if rows is not None:
        adam.scatter(rows, leaves)
    for k in gmap._cols:  # atol: m = 0.9 m + 0.1 g cancels, leaving float32 rounding of terms ~0.3
        np.testing.assert_allclose(gmap[k].numpy(), expect[k].numpy(), rtol=1e-6, atol=1e-7, err_msg=k)
    touched = torch.zeros(N, dtype=torch.bool)
    touched[torch.cat(seen)] = True
    assert 0 < int(touched.sum()) < N
    for k in gmap._cols:  # every column of a row never updated is bit for bit what it was
        assert torch.equal(gmap[k][~touched], before[k][~touched]), k
    np.testing.assert_array_equal(gmap["means"][at[zero]].numpy(), before["means"][at[zero]].numpy())


EDGE_GRADS = [0.0, 1e-40, -1e-40, 1e-20, -1e-20, 1e-5, -3.0, 1e20, -1e20]


@pytest.mark.parametrize("path", ["kernel", "torch"])
def test_sparse_adam_is_finite_and_exact_on_edge_gradients(path):
    """Fresh splats (step count 0, zero moments) and older ones, with zero, subnormal (1e-40), tiny
    (1e-20) and huge (1e20) gradients: three steps give finite values equal to a float64 Adam. A
    float g * g underflows or overflows at these, and with -ffast-math on an AVX2-only CPU the first
    step of a fresh splat with g = 1e-20 was NaN."""
    gmap = GaussianMap()
    lrs = {"means": 1e-2, "quats": 1e-3, "log_scales": 5e-3, "opacity_logits": 5e-2, "colors": 2.5e-3}
    adam = SparseAdam(gmap, lrs)
    n = 2 * len(EDGE_GRADS)  # each gradient on a fresh splat and on one 40 steps old
    gmap.append(frame=0, **_params(n, 7))
    old = torch.arange(n) >= len(EDGE_GRADS)
    gmap["adam_step"][old] = 40
    for name in PARAM_SHAPES:
        gmap[f"adam_m.{name}"][old] = 1e-3
        gmap[f"adam_v.{name}"][old] = 1e-6
    grads = torch.tensor(EDGE_GRADS * 2, dtype=torch.float32)
    expect = {k: gmap[k].clone() for k in gmap._cols}
    visible = torch.arange(n)
    for _ in range(3):
        leaves = adam.leaves()
        for name, p in leaves.items():
            p.grad = grads.view((-1,) + (1,) * (p.dim() - 1)).expand(p.shape).contiguous()
        expect["adam_step"] += 1
        for name, p in leaves.items():
            new_p, new_m, new_v = _adam_reference(expect[name], p.grad, expect[f"adam_m.{name}"],
                                                  expect[f"adam_v.{name}"], expect["adam_step"], lrs[name])
            expect[name], expect[f"adam_m.{name}"], expect[f"adam_v.{name}"] = (
                new_p.float(), new_m.float(), new_v.float())
        if path == "kernel":
            adam.step(leaves, visible)
        else:
            adam._step_torch(leaves, visible, None)
            for p in leaves.values():
                p.grad = None
    for k in gmap._cols:  # atol: one step of float32's subnormals (float ops round moments ~1e-41 there)
        assert torch.isfinite(gmap[k].float()).all(), k
        np.testing.assert_allclose(gmap[k].numpy(), expect[k].numpy(), rtol=1e-6, atol=1.5e-45, err_msg=k)
    moved = (gmap["means"] - _params(n, 7)["means"]).abs().amax(1)
    huge = grads.abs() == 1e20
    assert (moved[huge] > 0.5 * lrs["means"]).all()  # a huge gradient still moves a splat by ~lr

"""Map store growth and compaction, and the sparse Adam against torch's own Adam."""

import numpy as np
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

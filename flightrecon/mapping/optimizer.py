"""Sparse Adam over the map's parameter columns, with per-splat step counts.

The moments are columns of the GaussianMap, so they grow and are pruned with the splats. Only the
splats a view touched (radii > 0) are updated: an online map is mostly out of view, and updating it
densely would let stale momentum drift unseen splats and cost time proportional to the whole map.
Each splat counts its own steps, so a splat added late gets Adam's full bias correction.
"""

from __future__ import annotations

import torch

from flightrecon.mapping.store import PARAM_SHAPES, GaussianMap


class SparseAdam:
    def __init__(self, gmap: GaussianMap, lrs: dict[str, float], betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-15) -> None:
        unknown = set(lrs) - set(PARAM_SHAPES)
        if unknown:
            raise ValueError(f"no parameter named {sorted(unknown)}")
        self.gmap = gmap
        self.lrs = dict(lrs)
        self.betas = betas
        self.eps = eps
        for name, shape in PARAM_SHAPES.items():
            gmap.add_column(f"adam_m.{name}", shape, torch.float32)
            gmap.add_column(f"adam_v.{name}", shape, torch.float32)
        gmap.add_column("adam_step", (), torch.int32)

    def leaves(self) -> dict[str, torch.Tensor]:
        """Views of the live parameter rows that require grad; valid until the map changes size."""
        return {name: self.gmap[name].requires_grad_(True) for name in PARAM_SHAPES}

    @torch.no_grad()
    def step(self, leaves: dict[str, torch.Tensor], visible: torch.Tensor) -> None:
        """Adam update of the rows in `visible` (index tensor) from `leaves[*].grad`; grads cleared."""
        b1, b2 = self.betas
        steps = self.gmap["adam_step"]
        t = steps[visible] + 1
        steps[visible] = t
        t = t.to(torch.float32)
        bc1 = 1.0 - torch.pow(b1, t)
        bc2_sqrt = torch.sqrt(1.0 - torch.pow(b2, t))
        for name, p in leaves.items():
            g = p.grad
            if g is None:
                continue
            lr = self.lrs.get(name, 0.0)
            if lr > 0.0:
                g = g[visible]
                m_col = self.gmap[f"adam_m.{name}"]
                v_col = self.gmap[f"adam_v.{name}"]
                m = m_col[visible].mul_(b1).add_(g, alpha=1.0 - b1)
                v = v_col[visible].mul_(b2).addcmul_(g, g, value=1.0 - b2)
                m_col[visible] = m
                v_col[visible] = v
                shape = (-1,) + (1,) * (m.dim() - 1)
                denom = (v.sqrt() / bc2_sqrt.view(shape)).add_(self.eps)
                p[visible] -= lr * (m / bc1.view(shape)) / denom
            p.grad = None

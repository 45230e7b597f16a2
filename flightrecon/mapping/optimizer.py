"""Sparse Adam over the map's parameter columns, with per-splat step counts.

The moments are columns of the GaussianMap, so they grow and are pruned with the splats. Only the
splats a view touched (radii > 0) are updated: an online map is mostly out of view, and updating it
densely would let stale momentum drift unseen splats and cost time proportional to the whole map.
Each splat counts its own steps, so a splat added late gets Adam's full bias correction.

A run of steps on splats outside the others' reach can train a `gather`ed copy of their parameters
(the rasterizer's inputs) and `scatter` it back once, so per-step cost scales with those rows, not
the map; the moments and step counts stay in the map, where `step` updates them at the gathered
rows. On the CPU one C++ call (csrc/optimizer.cpp) does a whole step; elsewhere torch ops do.
"""

from __future__ import annotations

import torch

from flightrecon.mapping.store import PARAM_SHAPES, GaussianMap
from flightrecon.render import load_extension


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
        """The map's parameter columns, requiring grad (views of the live rows, valid until the map
        changes size): the leaves of a full-map step."""
        return {name: self.gmap[name].requires_grad_(True) for name in PARAM_SHAPES}

    def gather(self, rows: torch.Tensor) -> dict[str, torch.Tensor]:
        """Copies of the parameters at map `rows` (increasing indices), requiring grad: the leaves
        of steps with `rows=rows`, until `scatter`."""
        return {name: self.gmap[name].index_select(0, rows).requires_grad_(True) for name in PARAM_SHAPES}

    @torch.no_grad()
    def scatter(self, rows: torch.Tensor, leaves: dict[str, torch.Tensor]) -> None:
        """Write `gather(rows)`'s trained parameters back into the map (the moments are there already)."""
        for name in PARAM_SHAPES:
            self.gmap[name].index_copy_(0, rows, leaves[name])

    @torch.no_grad()
    def step(self, leaves: dict[str, torch.Tensor], visible: torch.Tensor,
             rows: torch.Tensor | None = None) -> None:
        """Adam update of the leaves' rows `visible` (unique indices) from `leaves[*].grad`; grads
        cleared. The leaves are the map's columns (`rows` None) or `gather(rows)`: the moments and
        step counts of leaf row i are then the map's at rows[i]. lr 0 freezes a parameter."""
        trained = [name for name, p in leaves.items() if p.grad is not None and self.lrs.get(name, 0.0) > 0.0]
        if visible.device.type == "cpu":
            load_extension().adam_step(
                [leaves[k].detach() for k in trained], [leaves[k].grad.contiguous() for k in trained],
                [self.gmap[f"adam_m.{k}"] for k in trained], [self.gmap[f"adam_v.{k}"] for k in trained],
                [self.lrs[k] for k in trained], self.gmap["adam_step"], visible.contiguous(),
                None if rows is None else rows.contiguous(), *self.betas, self.eps)
        else:
            self._step_torch({k: leaves[k] for k in trained}, visible, rows)
        for p in leaves.values():
            p.grad = None

    @torch.no_grad()
    def _step_torch(self, leaves: dict[str, torch.Tensor], visible: torch.Tensor,
                    rows: torch.Tensor | None) -> None:
        """The same update in torch ops, for maps off the CPU (every leaf given here is trained).
        One gather per column (index_select), in-place moment updates on the gathered rows and one
        scatter back (index_copy_): the fewest passes over the visible rows."""
        at = visible if rows is None else rows.index_select(0, visible)
        b1, b2 = self.betas
        steps = self.gmap["adam_step"]
        t = steps.index_select(0, at).add_(1)
        steps.index_copy_(0, at, t)
        t = t.to(torch.float64)  # 1 - 0.999^t in float loses ~5 digits to cancellation for young splats
        step_size = torch.pow(b1, t).neg_().add_(1.0).reciprocal_().float()  # 1 / bias correction 1
        bc2_sqrt = torch.pow(b2, t).neg_().add_(1.0).sqrt_().float()
        for name, p in leaves.items():
            g = p.grad.index_select(0, visible)
            m_col = self.gmap[f"adam_m.{name}"]
            v_col = self.gmap[f"adam_v.{name}"]
            m = m_col.index_select(0, at).mul_(b1).add_(g, alpha=1.0 - b1)
            v = v_col.index_select(0, at).mul_(b2).addcmul_(g, g, value=1.0 - b2)
            m_col.index_copy_(0, at, m)
            v_col.index_copy_(0, at, v)
            shape = (-1,) + (1,) * (m.dim() - 1)
            denom = v.sqrt_().div_(bc2_sqrt.view(shape)).add_(self.eps)
            update = m.mul_(step_size.view(shape)).div_(denom).mul_(self.lrs[name])
            p.index_copy_(0, visible, p.index_select(0, visible).sub_(update))

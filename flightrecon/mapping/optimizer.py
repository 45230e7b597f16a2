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

    def state_names(self) -> list[str]:
        """The map columns this optimizer reads and writes: parameters, moments and step counts."""
        return [*PARAM_SHAPES, *(f"adam_{k}.{name}" for k in "mv" for name in PARAM_SHAPES), "adam_step"]

    def gather(self, rows: torch.Tensor) -> dict[str, torch.Tensor]:
        """Copies of the optimizer's columns at `rows` (increasing indices), parameters requiring grad.

        A run of steps on splats outside the others' reach can work on these (`leaves` and `step` with
        `state=`) and `scatter` them back once: per-step cost then scales with the rows, not the map."""
        state = {k: self.gmap[k].index_select(0, rows) for k in self.state_names()}
        for name in PARAM_SHAPES:
            state[name].requires_grad_(True)
        return state

    @torch.no_grad()
    def scatter(self, rows: torch.Tensor, state: dict[str, torch.Tensor]) -> None:
        """Write a `gather`ed state back into the map's rows."""
        for k in self.state_names():
            self.gmap[k].index_copy_(0, rows, state[k])

    def leaves(self, state: dict[str, torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
        """The parameters that require grad: views of the map's live rows (valid until the map changes
        size) or those of a `gather`ed state."""
        cols = self.gmap if state is None else state
        return {name: cols[name].requires_grad_(True) for name in PARAM_SHAPES}

    @torch.no_grad()
    def step(self, leaves: dict[str, torch.Tensor], visible: torch.Tensor,
             state: dict[str, torch.Tensor] | None = None) -> None:
        """Adam update of the rows in `visible` (index tensor) from `leaves[*].grad`; grads cleared.

        The moments and step counts are the map's columns, or `state`'s when the leaves are a
        gathered state's. One gather per column (index_select), in-place moment updates on the
        gathered rows and one scatter back (index_copy_): the fewest passes over the visible rows."""
        cols = self.gmap if state is None else state
        b1, b2 = self.betas
        steps = cols["adam_step"]
        t = steps.index_select(0, visible).add_(1)
        steps.index_copy_(0, visible, t)
        t = t.to(torch.float32)
        step_size = torch.pow(b1, t).neg_().add_(1.0).reciprocal_()  # 1 / bias correction 1
        bc2_sqrt = torch.pow(b2, t).neg_().add_(1.0).sqrt_()
        for name, p in leaves.items():
            g = p.grad
            if g is None:
                continue
            lr = self.lrs.get(name, 0.0)
            if lr > 0.0:
                g = g.index_select(0, visible)
                m_col = cols[f"adam_m.{name}"]
                v_col = cols[f"adam_v.{name}"]
                m = m_col.index_select(0, visible).mul_(b1).add_(g, alpha=1.0 - b1)
                v = v_col.index_select(0, visible).mul_(b2).addcmul_(g, g, value=1.0 - b2)
                m_col.index_copy_(0, visible, m)
                v_col.index_copy_(0, visible, v)
                shape = (-1,) + (1,) * (m.dim() - 1)
                denom = v.sqrt_().div_(bc2_sqrt.view(shape)).add_(self.eps)
                update = m.mul_(step_size.view(shape)).div_(denom).mul_(lr)
                p.index_copy_(0, visible, p.index_select(0, visible).sub_(update))
            p.grad = None

"""`render_view_with_sums(...)`: one camera's render that also answers per-splat pixel sums.

design's key identity: with features f_i, the rendered image is F(p) = sum_i f_i w_i(p), so for
any pixel values v the per-splat sum S_i = sum_p v(p) w_i(p) is the gradient of sum_p v(p) F(p)
with respect to f_i. The loop renders the map once at each captured pose; that one render gives
the images (color, depth, normal) and, by a backward through it, every S_i the selectors need
(reliability evidence, coverage), instead of a render per question.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from flightrecon.render.api import RenderOutput, render


@dataclass
class RenderedView:
    """A single camera's RenderOutput ([1,H,W,k] images) and the feature leaf [N,D] it was made with."""

    output: RenderOutput
    features: Tensor

    def splat_sums(self, values: Tensor) -> Tensor:
        """S [N] = sum_p values(p) w_i(p) for pixel values [H,W] (one backward; the graph is kept).

        `values` are taken as constants: values computed from this render (a loss image) would
        otherwise carry its graph, and the backward would add sum_p F(p) dvalues(p)/df_i, a term
        that is not a pixel sum and has either sign."""
        with torch.enable_grad():
            (grad,) = torch.autograd.grad((self.output.features[0, ..., 0] * values.detach()).sum(), self.features,
                                          retain_graph=True)
        return grad[:, 0]


def render_view_with_sums(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
                          features: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int,
                          near: float = 0.05, far: float = 10.0,
                          outputs: Sequence[str] = ("features", "depth", "normal"),
                          backend: str = "auto") -> RenderedView:
    """Render one camera (viewmat [4,4] world-to-camera, K [3,3]) with features [N,D]; the splat
    parameters are taken as constants, only the features carry a graph (for `splat_sums`)."""
    leaf = features.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        out = render(means.detach(), quats.detach(), log_scales.detach(), opacity_logits.detach(), leaf,
                     viewmat[None], K[None], width, height, near=near, far=far, outputs=tuple(outputs),
                     backend=backend)
    return RenderedView(out, leaf)

"""The `reference` backend: the dense torch rasterizer behind the common API."""

from __future__ import annotations

from torch import Tensor

from flightrecon.render.projection import project, splat_axes
from flightrecon.render.reference import render_reference


def render_reference_backend(means: Tensor, quats: Tensor, log_scales: Tensor,
                             opacity_logits: Tensor, features: Tensor, viewmats: Tensor, Ks: Tensor,
                             width: int, height: int, near: float, far: float,
                             outputs: tuple[str, ...]) -> dict[str, Tensor]:
    raw = render_reference(means, quats, log_scales, opacity_logits, features, viewmats, Ks,
                           width, height, near, far)
    proj = project(means.detach(), *[a.detach() for a in splat_axes(quats, log_scales)],
                   viewmats, Ks, width, height, near, far)
    raw["radii"] = proj.radii.amax(-1)
    return raw

"""2DGS rasterizer: one batched functional API over three backends (cpu C++, cuda gsplat, reference)."""

from flightrecon.render.api import RenderOutput, render
from flightrecon.render.fisher import FisherDiag, render_fisher_diag

__all__ = ["FisherDiag", "RenderOutput", "render", "render_fisher_diag"]

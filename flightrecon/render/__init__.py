"""2DGS rasterizer: one batched functional API over three backends (cpu C++, cuda gsplat, reference)."""

from flightrecon.render.api import RenderOutput, render

__all__ = ["RenderOutput", "render"]

"""2DGS rasterizer: one batched functional API over three backends (cpu C++, cuda gsplat, reference)."""

from flightrecon.render.api import RenderOutput, render
from flightrecon.render.feature_sums import FeatureSums, sided_feature_sums
from flightrecon.render.fisher import FisherDiag, render_fisher_diag
from flightrecon.render.rendered_view import RenderedView, render_view_with_sums

__all__ = ["FeatureSums", "FisherDiag", "RenderOutput", "RenderedView", "render", "render_fisher_diag",
           "render_view_with_sums", "sided_feature_sums"]

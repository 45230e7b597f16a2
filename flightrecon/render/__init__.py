"""2DGS rasterizer: one batched functional API over three backends (cpu C++, cuda gsplat, reference).

Other packages reach the rasterizer and the C++ kernels (`load_extension`: image and optimizer
kernels share the extension) only through the names exported here."""

from flightrecon.render.api import RenderOutput, render, tile_grid
from flightrecon.render.backend_cpu import candidate_rows
from flightrecon.render.extension import load as load_extension
from flightrecon.render.feature_sums import FeatureSums, sided_feature_sums
from flightrecon.render.fisher import FisherDiag, render_fisher_diag
from flightrecon.render.rendered_view import RenderedView, render_view_with_sums

__all__ = ["FeatureSums", "FisherDiag", "RenderOutput", "RenderedView", "candidate_rows", "load_extension", "render",
           "render_fisher_diag", "render_view_with_sums", "sided_feature_sums", "tile_grid"]

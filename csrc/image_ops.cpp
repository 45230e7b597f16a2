// Separable Gaussian filtering of image planes for SSIM (flightrecon/mapping/image_metrics.py).
//
// The mapper's D-SSIM term filters 9 planes forward and 9 backward per iteration; torch's
// depthwise convolution on the CPU spends ~1-2 ms per call on that, several times what the
// arithmetic needs. Each output row here is one vertical pass (taps over rows, vectorized along the
// row) and one horizontal pass over it, so rows are independent: parallel and deterministic.
#include <omp.h>

#include <vector>

#include "bindings.h"

namespace {

template <typename S>
void blur_rows(const S* x, int64_t K, int64_t H, int64_t W, const S* taps, int T, S* out) {
  const int64_t Ho = H - T + 1, Wo = W - T + 1;
#pragma omp parallel
  {
    std::vector<S> col(W);
#pragma omp for schedule(static)
    for (int64_t r = 0; r < K * Ho; ++r) {
      const int64_t k = r / Ho, y = r % Ho;
      const S* src = x + (k * H + y) * W;
      S* c = col.data();
      for (int64_t i = 0; i < W; ++i) c[i] = taps[0] * src[i];
      for (int t = 1; t < T; ++t) {
        const S w = taps[t];
        const S* row = src + t * W;
#pragma omp simd
        for (int64_t i = 0; i < W; ++i) c[i] += w * row[i];
      }
      S* o = out + (k * Ho + y) * Wo;
      for (int64_t i = 0; i < Wo; ++i) o[i] = taps[0] * c[i];
      for (int t = 1; t < T; ++t) {
        const S w = taps[t];
#pragma omp simd
        for (int64_t i = 0; i < Wo; ++i) o[i] += w * c[i + t];
      }
    }
  }
}

torch::Tensor blur_valid(torch::Tensor x, torch::Tensor taps) {
  TORCH_CHECK(x.dim() == 3 && x.is_contiguous() && x.device().is_cpu(), "x must be contiguous CPU [K, H, W]");
  TORCH_CHECK(taps.dim() == 1 && taps.is_contiguous() && taps.scalar_type() == x.scalar_type(),
              "taps must be a contiguous 1-D tensor of x's dtype");
  const int64_t K = x.size(0), H = x.size(1), W = x.size(2), T = taps.size(0);
  TORCH_CHECK(T >= 1 && H >= T && W >= T, "the filter must fit inside the image");
  auto out = torch::empty({K, H - T + 1, W - T + 1}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "blur_valid", [&] {
    blur_rows<scalar_t>(x.data_ptr<scalar_t>(), K, H, W, taps.data_ptr<scalar_t>(), int(T), out.data_ptr<scalar_t>());
  });
  return out;
}

}  // namespace

void bind_image_ops(pybind11::module_& m) {
  m.def("blur_valid", &blur_valid, "separable filter of [K,H,W] planes by one 1-D kernel, 'valid' region");
}

// Per-pixel image operations of the mapper's loss, where torch's CPU kernels cost several times the
// arithmetic: separable Gaussian filtering of planes for SSIM (flightrecon/mapping/image_metrics.py)
// and the normals of a depth image with their backward (flightrecon/mapping/losses.py).
//
// The D-SSIM term filters 9 planes forward and 9 backward per iteration; torch's depthwise
// convolution spends ~1-2 ms per call on that. Each output row here is one vertical pass (taps over
// rows, vectorized along the row) and one horizontal pass over it, so rows are independent:
// parallel and deterministic. The depth normals were ~6.6 ms of CPU per iteration as a torch graph
// (products, slices, a cross product, a normalization and their backward) at 320x240. The normals
// are computed in double whatever the depth's dtype: the cross product squares the depth, which
// overflows float for depths above ~1e19 and underflows to subnormals below ~1e-19.
#include <omp.h>

#include <algorithm>
#include <cmath>
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

constexpr double NORMAL_EPS = 1e-12;  // F.normalize's floor on the norm

// Unnormalized normal c = dy x dx of the back-projected depth P = ray * depth at interior pixel (y, x)
// of one [H, W] image, and the central differences it came from, in double.
template <typename S>
inline void depth_cross(const S* d, const S* rays, int64_t W, int64_t y, int64_t x, double* dx, double* dy,
                        double* c) {
  const int64_t l = y * W + x - 1, r = y * W + x + 1, u = (y - 1) * W + x, b = (y + 1) * W + x;
  for (int k = 0; k < 3; ++k) {
    dx[k] = double(rays[3 * r + k]) * d[r] - double(rays[3 * l + k]) * d[l];
    dy[k] = double(rays[3 * b + k]) * d[b] - double(rays[3 * u + k]) * d[u];
  }
  c[0] = dy[1] * dx[2] - dy[2] * dx[1];
  c[1] = dy[2] * dx[0] - dy[0] * dx[2];
  c[2] = dy[0] * dx[1] - dy[1] * dx[0];
}

template <typename S>
void normals_forward(const S* depth, const S* rays, int64_t B, int64_t H, int64_t W, S* out) {
#pragma omp parallel for schedule(static)
  for (int64_t row = 0; row < B * H; ++row) {
    const int64_t bi = row / H, y = row % H;
    const S* d = depth + bi * H * W;
    S* o = out + row * W * 3;
    std::fill(o, o + W * 3, S(0));
    if (y == 0 || y == H - 1) continue;
    for (int64_t x = 1; x < W - 1; ++x) {
      double dx[3], dy[3], c[3];
      depth_cross(d, rays, W, y, x, dx, dy, c);
      const double inv = 1.0 / std::max(std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), NORMAL_EPS);
      for (int k = 0; k < 3; ++k) o[3 * x + k] = S(c[k] * inv);
    }
  }
}

// Gradient of the depth from that of the normals: per interior pixel, through the normalization
// and the cross product to the two central differences (gdx, gdy), then each depth pixel gathers the
// differences it entered (+ for the right/lower neighbour's, - for the left/upper one's) along its ray.
template <typename S>
void normals_backward(const S* depth, const S* rays, const S* gn, int64_t B, int64_t H, int64_t W, S* gdepth) {
  std::vector<double> gdx(size_t(B * H * W) * 3, 0.0), gdy(size_t(B * H * W) * 3, 0.0);
#pragma omp parallel for schedule(static)
  for (int64_t row = 0; row < B * H; ++row) {
    const int64_t bi = row / H, y = row % H;
    if (y == 0 || y == H - 1) continue;
    const S* d = depth + bi * H * W;
    for (int64_t x = 1; x < W - 1; ++x) {
      double dx[3], dy[3], c[3];
      depth_cross(d, rays, W, y, x, dx, dy, c);
      const double norm = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
      const S* g = gn + (row * W + x) * 3;
      double gc[3];
      if (norm > NORMAL_EPS) {
        const double inv = 1.0 / norm;
        const double dot = (c[0] * g[0] + c[1] * g[1] + c[2] * g[2]) * inv;
        for (int k = 0; k < 3; ++k) gc[k] = (g[k] - c[k] * inv * dot) * inv;
      } else {
        for (int k = 0; k < 3; ++k) gc[k] = g[k] / NORMAL_EPS;
      }
      double* ox = &gdx[(row * W + x) * 3];
      double* oy = &gdy[(row * W + x) * 3];
      // c = dy x dx: d/d(dy) = dx x gc, d/d(dx) = gc x dy
      oy[0] = dx[1] * gc[2] - dx[2] * gc[1];
      oy[1] = dx[2] * gc[0] - dx[0] * gc[2];
      oy[2] = dx[0] * gc[1] - dx[1] * gc[0];
      ox[0] = gc[1] * dy[2] - gc[2] * dy[1];
      ox[1] = gc[2] * dy[0] - gc[0] * dy[2];
      ox[2] = gc[0] * dy[1] - gc[1] * dy[0];
    }
  }
#pragma omp parallel for schedule(static)
  for (int64_t row = 0; row < B * H; ++row) {
    const int64_t y = row % H;
    for (int64_t x = 0; x < W; ++x) {
      double gp[3] = {0, 0, 0};
      const int64_t q = row * W + x;
      for (int k = 0; k < 3; ++k) {
        if (x > 0) gp[k] += gdx[3 * (q - 1) + k];
        if (x < W - 1) gp[k] -= gdx[3 * (q + 1) + k];
        if (y > 0) gp[k] += gdy[3 * (q - W) + k];
        if (y < H - 1) gp[k] -= gdy[3 * (q + W) + k];
      }
      const S* ray = rays + 3 * (y * W + x);
      gdepth[q] = S(ray[0] * gp[0] + ray[1] * gp[1] + ray[2] * gp[2]);
    }
  }
}

void check_depth(const torch::Tensor& depth, const torch::Tensor& rays) {
  TORCH_CHECK(depth.dim() == 3 && depth.is_contiguous() && depth.device().is_cpu(),
              "depth must be contiguous CPU [B, H, W]");
  TORCH_CHECK(rays.dim() == 3 && rays.size(0) == depth.size(1) && rays.size(1) == depth.size(2) && rays.size(2) == 3 &&
              rays.is_contiguous() && rays.scalar_type() == depth.scalar_type(),
              "rays must be contiguous [H, W, 3] of the depth's dtype");
}

torch::Tensor depth_normals(torch::Tensor depth, torch::Tensor rays) {
  check_depth(depth, rays);
  auto out = torch::empty({depth.size(0), depth.size(1), depth.size(2), 3}, depth.options());
  AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "depth_normals", [&] {
    normals_forward<scalar_t>(depth.data_ptr<scalar_t>(), rays.data_ptr<scalar_t>(), depth.size(0), depth.size(1),
                              depth.size(2), out.data_ptr<scalar_t>());
  });
  return out;
}

torch::Tensor depth_normals_backward(torch::Tensor depth, torch::Tensor rays, torch::Tensor grad) {
  check_depth(depth, rays);
  TORCH_CHECK(grad.is_contiguous() && grad.numel() == depth.numel() * 3 && grad.scalar_type() == depth.scalar_type(),
              "the normals' gradient must be contiguous [B, H, W, 3]");
  auto out = torch::empty_like(depth);
  AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "depth_normals_backward", [&] {
    normals_backward<scalar_t>(depth.data_ptr<scalar_t>(), rays.data_ptr<scalar_t>(), grad.data_ptr<scalar_t>(),
                               depth.size(0), depth.size(1), depth.size(2), out.data_ptr<scalar_t>());
  });
  return out;
}

}  // namespace

void bind_image_ops(pybind11::module_& m) {
  m.def("depth_normals", &depth_normals, "unit normals [B,H,W,3] of depth [B,H,W] along rays [H,W,3]; 0 on the border");
  m.def("depth_normals_backward", &depth_normals_backward, "gradient of the depth from that of depth_normals");
  m.def("blur_valid", &blur_valid, "separable filter of [K,H,W] planes by one 1-D kernel, 'valid' region");
}

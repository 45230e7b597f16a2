// Sided feature sums of the rasterizer, for 2D GauSS-MI's view scoring: per camera, the sum over
// pixels of a rendered one-channel feature that each splat takes from the side the camera sees
// (Eq. 12 of docs/equations.md: value[0] where w = n . (c - mu) / |c - mu| > w_min, value[1] where
// w < -w_min, 0 otherwise, times |w| when `weighted`). The forward's stages with one feature
// channel and a camera per thread.
//
// With floor > 0, a pixel stops before a splat of its tile's depth-ordered list once its
// transmittance times the largest feature from there to the list's end is below the floor: the
// features are >= 0 and the weights of what follows sum to at most that transmittance, so what it
// leaves out is at most the floor. The exact sum lies in [sum, sum + bound], bound = the sum over
// the stopped pixels of transmittance x that largest feature (float rounding aside). A list's tail
// of zero features stops every pixel at no cost to the bound.
#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "rasterize_torch.h"

namespace raster {
namespace {

// The value the splat at position s takes for a camera centered at `center`: the side it shows the
// camera (w), gated by w_min, weighted by |w| if asked.
template <typename S>
S sided_feature(const SplatGroups<S>& G, int64_t s, const double* center, const S* value, double w_min,
                bool weighted) {
  const S* m = &G.mean[3 * s];
  const S* nrm = &G.n[3 * s];
  double d[3], len = 0;
  for (int r = 0; r < 3; ++r) {
    d[r] = center[r] - double(m[r]);
    len += d[r] * d[r];
  }
  len = std::sqrt(len);
  if (!(len > 0)) return S(0);
  const double w = (d[0] * double(nrm[0]) + d[1] * double(nrm[1]) + d[2] * double(nrm[2])) / len;
  const int64_t i = G.id[s];
  const double v = w > w_min ? double(value[2 * i]) : (w < -w_min ? double(value[2 * i + 1]) : 0.0);
  return S(weighted ? std::fabs(w) * v : v);
}

template <typename S>
std::vector<torch::Tensor> feature_sums_impl(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                             torch::Tensor opac, torch::Tensor sided, torch::Tensor viewmats,
                                             torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                             double w_min, bool weighted, double floor) {
  const int64_t N = means.size(0), C = viewmats.size(0);
  auto sums = torch::zeros({C}, torch::kFloat64), bound = torch::zeros({C}, torch::kFloat64);
  const Settings st = settings_of(W, H, near, far);
  const int tiles = st.tiles_x * st.tiles_y;
  std::vector<Camera> cams;
  std::vector<std::array<double, 3>> centers;
  for (int64_t c = 0; c < C; ++c) {
    cams.push_back(camera_of(viewmats, Ks, c));
    const Camera& k = cams.back();
    std::array<double, 3> o{};
    for (int q = 0; q < 3; ++q) o[q] = -(k.R[q] * k.t[0] + k.R[3 + q] * k.t[1] + k.R[6 + q] * k.t[2]);
    centers.push_back(o);
  }
  const S* value = sided.data_ptr<S>();
  double* out_sum = sums.data_ptr<double>();
  double* out_bound = bound.data_ptr<double>();
  std::vector<Stats> per(C);
  const double tc = omp_get_wtime();
  const SplatGroups<S> groups = group_splats(means.data_ptr<S>(), U.data_ptr<S>(), V.data_ptr<S>(), n.data_ptr<S>(),
                                             opac.data_ptr<S>(), N, C > 1);
  const double groups_s = omp_get_wtime() - tc;
  const Flags fl{false, false, false, false};
#pragma omp parallel
  {
    Projected<S> P(N);
    Visible vis;
    std::vector<S> feat(N, S(0)), img(size_t(W * H)), alpha(size_t(W * H));
#pragma omp for schedule(dynamic, 1)
    for (int64_t c = 0; c < C; ++c) {
      Stats& sc = per[c];
      double t0 = omp_get_wtime();
      project_camera<S>(groups, cams[c], st, P, vis);
      for (const int32_t s : vis.binned) feat[groups.id[s]] = sided_feature(groups, s, centers[c].data(), value,
                                                                            w_min, weighted);
      sc.project += omp_get_wtime() - t0;
      sc.tests += vis.tests;
      sc.projected += vis.projected;
      sc.binned += int64_t(vis.binned.size());
      Bins<S> B = bin_and_sort(P, groups, vis, feat.data(), 1, st, sc);
      if (floor > 0) {
        B.stop_T.resize(B.ids.size());
        B.left_max.resize(B.ids.size());
        for (int t = 0; t < tiles; ++t) {
          S most = 0;
          for (int64_t e = B.offsets[t + 1] - 1; e >= B.offsets[t]; --e) {
            most = std::max(most, B.rec[size_t(B.ids[e]) * B.R + REC]);
            B.left_max[e] = most;
            B.stop_T[e] = most > 0 ? S(floor) / most : std::numeric_limits<S>::infinity();
          }
        }
      }
      t0 = omp_get_wtime();
      const FwdOut<S> out{img.data(), alpha.data(), nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr};
      double left = 0;
      for (int t = 0; t < tiles; ++t) {
        const TileWork tw = forward_tile<S, false>(t, B, 1, st, fl, out);
        sc.evals += tw.evals;
        sc.blends += tw.blends;
        left += tw.left;
      }
      sc.blend += omp_get_wtime() - t0;
      double total = 0;
      for (int64_t q = 0; q < W * H; ++q) total += double(img[q]);
      out_sum[c] = total;
      out_bound[c] = left;
      for (const int32_t s : vis.binned) feat[groups.id[s]] = S(0);
    }
  }
  g_stats = Stats();
  g_stats.by_camera = true;
  for (const Stats& sc : per) g_stats.add(sc);
  g_stats.project += groups_s;
  return {sums, bound};
}

}  // namespace

std::vector<torch::Tensor> feature_sums(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                        torch::Tensor opac, torch::Tensor sided, torch::Tensor viewmats,
                                        torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                        double w_min, bool weighted, double floor) {
  TORCH_CHECK(sided.dim() == 2 && sided.size(0) == means.size(0) && sided.size(1) == 2,
              "sided values must be [N, 2] (front, back)");
  if (means.scalar_type() == torch::kFloat64)
    return feature_sums_impl<double>(means, U, V, n, opac, sided, viewmats, Ks, W, H, near, far, w_min, weighted,
                                     floor);
  return feature_sums_impl<float>(means, U, V, n, opac, sided, viewmats, Ks, W, H, near, far, w_min, weighted,
                                  floor);
}

}  // namespace raster

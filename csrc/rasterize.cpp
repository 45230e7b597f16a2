// The rasterizer's Python functions (rasterize.h describes the pipeline and lists its files): the
// entry points of the forward, backward and feature sums (defined in their stage files), the
// candidate rows of one camera, the phase statistics, and the camera input they all read.
#include <omp.h>

#include <map>
#include <numeric>
#include <string>
#include <vector>

#include "bindings.h"
#include "rasterize_torch.h"

namespace raster {

Stats g_stats;

Camera camera_of(const torch::Tensor& viewmats, const torch::Tensor& Ks, int64_t c) {
  auto vm = viewmats[c].to(torch::kFloat64).contiguous();
  auto k = Ks[c].to(torch::kFloat64).contiguous();
  const double* v = vm.data_ptr<double>();
  const double* kk = k.data_ptr<double>();
  Camera cam;
  for (int r = 0; r < 3; ++r) {
    for (int q = 0; q < 3; ++q) cam.R[3 * r + q] = v[4 * r + q];
    cam.t[r] = v[4 * r + 3];
  }
  for (int q = 0; q < 9; ++q) cam.K[q] = kk[q];
  return cam;
}

const uint8_t* tile_flags(const torch::Tensor& keep_tiles, int64_t C, int64_t W, int64_t H) {
  if (keep_tiles.numel() == 0) return nullptr;
  const int64_t tiles = ((W + TS - 1) / TS) * ((H + TS - 1) / TS);
  TORCH_CHECK(keep_tiles.scalar_type() == torch::kUInt8 && keep_tiles.is_contiguous() && keep_tiles.dim() == 2 &&
                  keep_tiles.size(0) == C && keep_tiles.size(1) == tiles,
              "rasterizer: keep_tiles must be a contiguous uint8 tensor [cameras, tiles] = [", C, ", ", tiles,
              "] (the 16x16 tiles row by row), or empty for every tile");
  return keep_tiles.data_ptr<uint8_t>();
}

namespace {

// Increasing indices of the splats that pass project_splat's first test for one camera (with a
// float slack; candidate_mask): every splat the camera can draw is among them.
template <typename S>
torch::Tensor candidate_rows_impl(const torch::Tensor& means, const torch::Tensor& U, const torch::Tensor& V,
                                  const Camera& cam, const Settings& st) {
  const int64_t N = means.size(0);
  const std::vector<uint8_t> keep =
      candidate_mask(means.data_ptr<S>(), U.data_ptr<S>(), V.data_ptr<S>(), N, cam, st);
  const int64_t count = std::accumulate(keep.begin(), keep.end(), int64_t(0));
  auto rows = torch::empty({count}, torch::kInt64);
  int64_t* r = rows.data_ptr<int64_t>();
  for (int64_t i = 0; i < N; ++i)
    if (keep[i]) *r++ = i;
  return rows;
}

torch::Tensor candidate_rows(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor viewmat,
                             torch::Tensor K, int64_t W, int64_t H, double near, double far) {
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && U.sizes() == means.sizes() && V.sizes() == means.sizes(),
              "means, U, V must be [N, 3]");
  TORCH_CHECK(means.is_contiguous() && U.is_contiguous() && V.is_contiguous() &&
              U.scalar_type() == means.scalar_type() && V.scalar_type() == means.scalar_type(),
              "means, U, V must be contiguous and of one dtype");
  TORCH_CHECK(viewmat.sizes() == torch::IntArrayRef({4, 4}) && K.sizes() == torch::IntArrayRef({3, 3}),
              "one camera: viewmat [4, 4], K [3, 3]");
  const Camera cam = camera_of(viewmat.unsqueeze(0), K.unsqueeze(0), 0);
  const Settings st = settings_of(W, H, near, far);
  if (means.scalar_type() == torch::kFloat64) return candidate_rows_impl<double>(means, U, V, cam, st);
  return candidate_rows_impl<float>(means, U, V, cam, st);
}

}  // namespace
}  // namespace raster

void bind_rasterizer(pybind11::module_& m) {
  namespace py = pybind11;
  using raster::g_stats;
  py::class_<raster::RenderCache>(m, "RenderCache", "a single camera's projection and bins, kept by forward for backward")
      .def(py::init<>());
  // the last argument is a RenderCache or None: forward fills it, backward reads it
  m.def("forward", &raster::forward, "2DGS forward for C cameras");
  m.def("backward", &raster::backward, "2DGS backward (or FisherRF squared contributions) for C cameras");
  m.def("feature_sums", &raster::feature_sums, "per-camera pixel sums of a two-sided splat feature, with a tail cut");
  m.def("candidate_rows", &raster::candidate_rows, "indices of the splats one camera may draw (its frustum test)");
  m.def("num_threads", []() { return omp_get_max_threads(); });
  m.def("blend_ceiling", [](double seconds) {
    const raster::CeilingProbe c = raster::blend_ceiling(seconds);
    return std::map<std::string, double>{{"blend_per_s_thread", c.blend_per_s_thread},
                                         {"reject_per_s_thread", c.reject_per_s_thread},
                                         {"threads", double(c.threads)}};
  }, "the forward blend's evaluations per second per thread where nothing is wasted (the ceiling)");
  m.def("last_stats", []() {
    return std::map<std::string, double>{
        {"project_s", g_stats.project}, {"bin_s", g_stats.bin}, {"sort_s", g_stats.sort},
        {"blend_s", g_stats.blend}, {"reduce_s", g_stats.reduce}, {"chain_s", g_stats.chain},
        {"evals", double(g_stats.evals)}, {"blends", double(g_stats.blends)}, {"isects", double(g_stats.isects)},
        {"tests", double(g_stats.tests)}, {"projected", double(g_stats.projected)}, {"binned", double(g_stats.binned)},
        {"by_camera", double(g_stats.by_camera)}};
  }, "phase timings and pixel-splat evaluations of the last forward/backward call");
}

// The blend's ceiling on this CPU: the forward blend of a tile run where nothing is wasted. One
// splat facing the camera covers a whole 16x16 tile with alpha small enough that no pixel
// terminates, and is listed many times, so every group the loop visits has 8 live pixels and the
// records stay in cache. Measured twice, on all threads at once (as the mapper's blend runs): with
// every evaluation blending, and with the record's opacity lowered below the alpha gate so that
// every evaluation is rejected (the cheap path of a pixel the splat does not reach). A real blend of
// E evaluations of which B blend would take (E - B) / reject + B / blend seconds per thread at this
// ceiling; the gap to its measured time is what sparse tiles, partial groups, terminated pixels and
// cache misses cost.
#include <omp.h>

#include <stdexcept>
#include <vector>

#include "rasterize.h"

namespace raster {
namespace {

constexpr int PROBE_LIST = 256;  // records in the tile's list: T stays above T_MIN through them all
constexpr int PROBE_D = 3;

// The tile's bins: the real projection and binning of one splat, its record listed PROBE_LIST times;
// `reject`: with its opacity lowered so that no pixel reaches ALPHA_MIN.
Bins<float> probe_bins(const Settings& st, bool reject) {
  Camera cam{};
  cam.R[0] = cam.R[4] = cam.R[8] = 1.0;
  const double f = TS / 2.0;
  const double K[9] = {f, 0, f, 0, f, f, 0, 0, 1};
  std::copy(K, K + 9, cam.K);
  // 2 m in front, 2 m half-axes: u, v < 1 over the tile, so alpha = 0.02 exp(-rho / 2) > ALPHA_MIN
  const float mean[3] = {0, 0, 2}, U[3] = {2, 0, 0}, V[3] = {0, 2, 0}, n[3] = {0, 0, -1}, opac[1] = {0.02f};
  const float feat[PROBE_D] = {0.25f, 0.5f, 0.75f};
  const SplatGroups<float> G = group_splats<float>(mean, U, V, n, opac, 1, false);
  Projected<float> P(1);
  Visible vis;
  project_camera<float>(G, cam, st, P, vis);
  Stats unused;
  const Bins<float> one = bin_and_sort(P, G, vis, feat, PROBE_D, st, unused);
  if (one.splat.size() != 1 || one.rect[0] != 0 || one.rect[2] != TS - 1)
    throw std::logic_error("blend_ceiling: the probe splat does not cover its tile");
  Bins<float> b;
  b.R = one.R;
  std::vector<float> rec = one.rec;
  if (reject) rec[11] = float(ALPHA_MIN) * 0.9f;
  b.offsets = {0, PROBE_LIST};
  for (int k = 0; k < PROBE_LIST; ++k) {
    b.ids.push_back(k);
    b.splat.push_back(0);
    b.rect.insert(b.rect.end(), one.rect.begin(), one.rect.end());
    b.rec.insert(b.rec.end(), rec.begin(), rec.end());
  }
  return b;
}

// Evaluations per second per thread of the probe tile, run for `seconds` on every thread; `blends`
// counts those that blend.
double probe_rate(const Bins<float>& B, const Settings& st, double seconds, int& threads, int64_t& blends) {
  const Flags fl{true, true, true, true};  // the mapper's outputs: features, normal, depth, distortion
  int64_t evals = 0;
  blends = 0;
  double busy = 0;
#pragma omp parallel reduction(+ : evals, blends, busy)
  {
#pragma omp single
    threads = omp_get_num_threads();
    std::vector<float> img(TS * TS * (PROBE_D + 8));
    std::vector<int32_t> ids(2 * TS * TS);
    float* p = img.data();
    const int px = TS * TS;
    const FwdOut<float> out{p, p + PROBE_D * px, p + (PROBE_D + 1) * px, p + (PROBE_D + 4) * px,
                            p + (PROBE_D + 5) * px, p + (PROBE_D + 6) * px, p + (PROBE_D + 7) * px,
                            ids.data(), ids.data() + px};
    forward_tile<float, true>(0, B, PROBE_D, st, fl, out);  // warm up
    const double t0 = omp_get_wtime();
    double t = t0;
    while (t - t0 < seconds) {
      const TileWork w = forward_tile<float, true>(0, B, PROBE_D, st, fl, out);
      evals += w.evals;
      blends += w.blends;
      t = omp_get_wtime();
    }
    busy += t - t0;
  }
  return double(evals) / busy;
}

}  // namespace

CeilingProbe blend_ceiling(double seconds) {
  const Settings st = settings_of(TS, TS, 0.05, 10.0);
  CeilingProbe c;
  int64_t blends = 0;
  c.blend_per_s_thread = probe_rate(probe_bins(st, false), st, seconds / 2, c.threads, blends);
  if (blends == 0) throw std::logic_error("blend_ceiling: the blending probe did not blend");
  c.reject_per_s_thread = probe_rate(probe_bins(st, true), st, seconds / 2, c.threads, blends);
  if (blends != 0) throw std::logic_error("blend_ceiling: the rejecting probe blended");
  return c;
}

}  // namespace raster

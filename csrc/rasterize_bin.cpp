// Binning and sort stage of the rasterizer: the Morton order of the splats' means (SplatGroups'
// culling groups), and per camera the records of the binned splats, their depth order and each
// tile's list of them in that order (Bins). Both sorts are one stable radix sort.
#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

#include "rasterize.h"

namespace raster {
namespace {

constexpr int MORTON_BITS = 10;  // per axis

// Stable LSD radix sort of ids by 32-bit keys (8 bits a pass; passes whose byte is the same for
// every key are skipped): ids that enter in increasing order keep it among equal keys.
inline void radix_sort(std::vector<uint32_t>& key, std::vector<int32_t>& id) {
  const size_t n = key.size();
  std::vector<uint32_t> k2(n);
  std::vector<int32_t> i2(n);
  for (int shift = 0; shift < 32; shift += 8) {
    size_t count[257] = {0};
    for (size_t e = 0; e < n; ++e) ++count[((key[e] >> shift) & 0xffu) + 1];
    if (n == 0 || count[((key[0] >> shift) & 0xffu) + 1] == n) continue;
    for (int b = 0; b < 256; ++b) count[b + 1] += count[b];
    for (size_t e = 0; e < n; ++e) {
      const size_t d = count[(key[e] >> shift) & 0xffu]++;
      k2[d] = key[e];
      i2[d] = id[e];
    }
    key.swap(k2);
    id.swap(i2);
  }
}

// The low MORTON_BITS bits of v spread to every third bit.
inline uint32_t spread_bits(uint32_t v) {
  v &= 0x3ffu;
  v = (v | (v << 16)) & 0x030000ffu;
  v = (v | (v << 8)) & 0x0300f00fu;
  v = (v | (v << 4)) & 0x030c30c3u;
  v = (v | (v << 2)) & 0x09249249u;
  return v;
}

// The stable radix sort keeps equal keys in record (position) order, but the depth order breaks
// ties by the lower splat id: runs of equal keys are put in id order.
inline void ties_by_id(const std::vector<uint32_t>& key, std::vector<int32_t>& order, const std::vector<int32_t>& splat) {
  const size_t n = key.size();
  for (size_t a = 0, b; a < n; a = b) {
    for (b = a + 1; b < n && key[b] == key[a]; ++b) {}
    if (b - a > 1)
      std::sort(order.begin() + a, order.begin() + b, [&splat](int32_t x, int32_t y) { return splat[x] < splat[y]; });
  }
}

}  // namespace

template <typename S>
std::vector<int32_t> morton_order(const S* means, int64_t N) {
  if (N == 0) return {};
  double lo[3] = {means[0], means[1], means[2]}, hi[3] = {means[0], means[1], means[2]};
  for (int64_t i = 1; i < N; ++i)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], double(means[3 * i + a]));
      hi[a] = std::max(hi[a], double(means[3 * i + a]));
    }
  constexpr double top = (1 << MORTON_BITS) - 1;
  double scale[3];
  for (int a = 0; a < 3; ++a) scale[a] = hi[a] > lo[a] ? top / (hi[a] - lo[a]) : 0.0;
  std::vector<uint32_t> key(N);
  std::vector<int32_t> id(N);
  for (int64_t i = 0; i < N; ++i) {
    uint32_t code = 0;
    for (int a = 0; a < 3; ++a) {
      const double q = (double(means[3 * i + a]) - lo[a]) * scale[a];
      code |= spread_bits(q > 0 ? uint32_t(std::min(q, top)) : 0u) << a;
    }
    key[i] = code;
    id[i] = int32_t(i);
  }
  radix_sort(key, id);
  return id;
}

template <typename S>
Bins<S> bin_and_sort(const Projected<S>& P, const SplatGroups<S>& G, const Visible& vis, const S* feat, int D,
                     const Settings& st, Stats& stats, const uint8_t* keep_tile) {
  const int tiles = st.tiles_x * st.tiles_y;
  const double t0 = omp_get_wtime();
  Bins<S> b;
  // Records of the splats that touch the image, packed in position order (sequential reads).
  const int64_t V = int64_t(vis.binned.size());
  b.splat.resize(V);
  b.R = REC + D;
  b.rect.resize(4 * size_t(V));
  b.rec.resize(size_t(V) * b.R);
#pragma omp parallel for schedule(static)
  for (int64_t k = 0; k < V; ++k) {
    const size_t s = size_t(vis.binned[k]);
    const int64_t i = G.id[s];
    b.splat[k] = int32_t(i);
    S* q = &b.rec[size_t(k) * b.R];
    for (int c = 0; c < 9; ++c) q[c] = P.M[9 * s + c];
    q[9] = P.m2d[2 * s];
    q[10] = P.m2d[2 * s + 1];
    q[11] = G.opac[s];
    for (int c = 0; c < 3; ++c) q[12 + c] = P.nrm[3 * s + c];
    for (int d = 0; d < D; ++d) q[REC + d] = feat[i * D + d];
    for (int c = 0; c < 4; ++c) b.rect[4 * k + c] = P.rect[4 * s + c];
  }
  const double t1 = omp_get_wtime();
  // Depth order with ties by splat id: a binned splat has depth > near > 0, whose float bits order
  // like the values, so an integer sort of the records gives it.
  std::vector<int32_t> order(V);
  for (int64_t k = 0; k < V; ++k) order[k] = int32_t(k);
  if constexpr (std::is_same<S, float>::value) {
    std::vector<uint32_t> key(V);
    for (int64_t k = 0; k < V; ++k) std::memcpy(&key[k], &P.depth[vis.binned[k]], sizeof(uint32_t));
    radix_sort(key, order);
    ties_by_id(key, order, b.splat);
  } else {  // double depths do not fit the key
    const S* depth = P.depth.data();
    const int32_t *pos = vis.binned.data(), *id = b.splat.data();
    std::sort(order.begin(), order.end(), [depth, pos, id](int32_t a, int32_t c) {
      return depth[pos[a]] < depth[pos[c]] || (depth[pos[a]] == depth[pos[c]] && id[a] < id[c]);
    });
  }
  const double t2 = omp_get_wtime();
  // Tiles list their records in depth order.
  b.offsets.assign(tiles + 1, 0);
  auto kept = [keep_tile](int t) { return keep_tile == nullptr || keep_tile[t] != 0; };
  for (int64_t k = 0; k < V; ++k) {
    const int* r = &b.rect[4 * k];
    for (int ty = r[1] / TS; ty <= r[3] / TS; ++ty)
      for (int tx = r[0] / TS; tx <= r[2] / TS; ++tx)
        if (kept(ty * st.tiles_x + tx)) ++b.offsets[ty * st.tiles_x + tx + 1];
  }
  for (int t = 0; t < tiles; ++t) b.offsets[t + 1] += b.offsets[t];
  b.ids.resize(b.offsets[tiles]);
  std::vector<int64_t> fill(b.offsets.begin(), b.offsets.end() - 1);
  for (int64_t k : order) {
    const int* r = &b.rect[4 * k];
    for (int ty = r[1] / TS; ty <= r[3] / TS; ++ty)
      for (int tx = r[0] / TS; tx <= r[2] / TS; ++tx)
        if (kept(ty * st.tiles_x + tx)) b.ids[fill[ty * st.tiles_x + tx]++] = int32_t(k);
  }
  stats.bin += (t1 - t0) + (omp_get_wtime() - t2);
  stats.sort += t2 - t1;
  stats.isects += int64_t(b.ids.size());
  return b;
}

template std::vector<int32_t> morton_order(const float*, int64_t);
template std::vector<int32_t> morton_order(const double*, int64_t);
template Bins<float> bin_and_sort(const Projected<float>&, const SplatGroups<float>&, const Visible&, const float*,
                                  int, const Settings&, Stats&, const uint8_t*);
template Bins<double> bin_and_sort(const Projected<double>&, const SplatGroups<double>&, const Visible&,
                                   const double*, int, const Settings&, Stats&, const uint8_t*);

}  // namespace raster

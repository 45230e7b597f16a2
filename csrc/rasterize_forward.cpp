// Forward blend of the rasterizer: per tile, its splats front to back (depth order), each pixel's
// weight w = alpha T with T the transmittance left by the splats before it, until T falls below
// T_MIN (Eq. 1 of docs/equations.md). forward_tile sets up a tile's pixels and writes its images;
// the splat loop over the tile has two twins: forward_splats_avx2 (float, AVX2 registers) and
// forward_splats_generic (any S; the compiler vectorizes its pixel loops), with the same arithmetic
// per pixel. forward runs the stages for each camera: project, bin and sort, blend.
#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <type_traits>
#include <vector>

#include "rasterize_blend.h"
#include "rasterize_torch.h"

namespace raster {
namespace {

// One tile's pixels and what the blend accumulates at them, by slot (TP, slot_pixel): what both
// splat loops read and update, and what forward_tile writes out.
template <typename S>
struct FwdTile {
  int tx, ty;
  int64_t b0, b1;  // the tile's records: B.ids[b0, b1), in depth order
  alignas(64) S px[TP], py[TP], T[TP], act[TP];  // pixel centers, transmittance, not yet terminated
  alignas(64) S accA[TP], accZ[TP], accM[TP], accM2[TP], medz[TP];
  alignas(64) int32_t last[TP], medj[TP];
  std::vector<S> accF, accN;  // [D][TP], [3][TP] (normals only when rendered)
  FwdTile(int tile, const Bins<S>& B, int D, const Settings& st, const Flags& fl)
      : tx(tile % st.tiles_x), ty(tile / st.tiles_x), b0(B.offsets[tile]),
        b1(B.offsets[tile + 1]),
        accF(size_t(D) * TP, S(0)), accN(fl.normal ? 3 * TP : 0, S(0)) {
    for (int p = 0; p < TP; ++p) {
      const SlotPixel sl = slot_pixel(p, tx, ty, st.W, st.H);
      px[p] = S(sl.x) + S(0.5);
      py[p] = S(sl.y) + S(0.5);
      act[p] = sl.in_image ? S(1) : S(0);
      T[p] = S(1);
      accA[p] = accZ[p] = accM[p] = accM2[p] = medz[p] = S(0);
      last[p] = 0;
      medj[p] = -1;
    }
  }
};

#if FR_AVX2
// The same per-pixel arithmetic as forward_splats_generic, in AVX2 registers: one group of 8
// pixels at a time (8 columns of a row, or 4 of two rows for a narrow box), its weights going
// straight into the accumulators (only the groups a splat covers are visited), the blend masks
// kept in registers instead of masked stores, and exp inline. Records are prefetched a few
// splats ahead (the tile lists them in depth order, scattered in memory).
template <bool TRACK>
TileWork forward_splats_avx2(FwdTile<float>& t, const Bins<float>& B, int D, const Settings& st, const Flags& fl,
                             uint32_t* out_blended) {
  const int tx = t.tx, ty = t.ty;
  const int64_t b0 = t.b0, b1 = t.b1;
  const float *px = t.px, *py = t.py;
  float *T = t.T, *act = t.act, *accA = t.accA, *accZ = t.accZ, *accM = t.accM, *accM2 = t.accM2, *medz = t.medz;
  int32_t *last = t.last, *medj = t.medj;
  std::vector<float>& accF = t.accF;
  std::vector<float>& accN = t.accN;
  const float near = float(st.near), mscale = float(st.far / (st.far - st.near));
  int64_t evals = 0, blends = 0;
  uint32_t live[TS + 1] = {};  // per row, a bit for each pixel in the image not yet terminated
  int rows_alive = 0;
  for (int r = 0; r < TS; ++r) {
    live[r] = ty * TS + r < st.H ? (1u << std::min(TS, st.W - tx * TS)) - 1 : 0u;
    rows_alive += live[r] != 0;
  }
  const bool dz = fl.depth || fl.dist;
  const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f), vnear = _mm256_set1_ps(near);
  const __m256 amax = _mm256_set1_ps(float(ALPHA_MAX)), amin = _mm256_set1_ps(float(ALPHA_MIN));
  const __m256 tmin = _mm256_set1_ps(float(T_MIN)), half = _mm256_set1_ps(0.5f);
  const __m256 vmscale = _mm256_set1_ps(mscale);
  const bool cut = !B.stop_T.empty();
  double left = 0;
  constexpr int AHEAD = 8;
  for (int64_t jj = b0; jj < b1 && rows_alive > 0; ++jj) {
    if (jj + AHEAD < b1) {
      const char* nx = reinterpret_cast<const char*>(&B.rec[size_t(B.ids[jj + AHEAD]) * B.R]);
      _mm_prefetch(nx, _MM_HINT_T0);
      _mm_prefetch(nx + 60, _MM_HINT_T0);
      _mm_prefetch(reinterpret_cast<const char*>(&B.rect[4 * size_t(B.ids[jj + AHEAD])]), _MM_HINT_T0);
    }
    const int k = B.ids[jj];
    const float* q = &B.rec[size_t(k) * B.R];
    const Span sp = span_of(&B.rect[4 * size_t(k)], tx, ty);
    const float* M = q;
    const float mx = q[9], my = q[10];
    const float* f = q + REC;
    const int32_t j = int32_t(jj - b0);
    const __m256 vmx = _mm256_set1_ps(mx), vo = _mm256_set1_ps(q[11]);
    const __m256 m6 = _mm256_set1_ps(M[6]), m7 = _mm256_set1_ps(M[7]), m8 = _mm256_set1_ps(M[8]);
    const __m256 vj = _mm256_castsi256_ps(_mm256_set1_epi32(j));
    const __m256 vj1 = _mm256_castsi256_ps(_mm256_set1_epi32(j + 1));
    uint32_t visited_blend = 0;  // Bins::blended of this record
    const __m256 vstop = _mm256_set1_ps(cut ? B.stop_T[jj] : 0.0f);
    // One group at slot pg (see load8); returns the mask of its pixels that terminate.
    auto group = [&](auto pair, int pg, const RowVec& rv, int bit) -> int {
      constexpr bool P = decltype(pair)::value;
      int cm = 0;  // pixels the cut stops before this record
      if (cut) {
        const __m256 T0 = load8<P>(T + pg), act0 = load8<P>(act + pg);
        const __m256 live0 = _mm256_cmp_ps(act0, zero, _CMP_NEQ_UQ);
        const __m256 early = _mm256_and_ps(live0, _mm256_cmp_ps(T0, vstop, _CMP_LT_OQ));
        cm = _mm256_movemask_ps(early);
        if (cm) {
          store8<P>(act + pg, _mm256_andnot_ps(early, act0));
          alignas(32) float ts[LANES];
          _mm256_store_ps(ts, _mm256_and_ps(early, T0));
          double sum = 0;
          for (const float v : ts) sum += double(v);
          left += sum * double(B.left_max[jj]);
          if (cm == _mm256_movemask_ps(live0)) return cm;
        }
      }
      evals += LANES;
      const __m256 x = load8<P>(px + pg);
      const Hit8 h = hit8(x, rv, vmx, m6, m7, m8);
      const __m256 nz = h.nz, z = h.z, g = h.g;
      const __m256 a = _mm256_min_ps(amax, _mm256_mul_ps(vo, g));
      const __m256 Tp = load8<P>(T + pg), actp = load8<P>(act + pg);
      const __m256 ok = _mm256_and_ps(
          _mm256_and_ps(nz, _mm256_cmp_ps(z, vnear, _CMP_GE_OQ)),
          _mm256_and_ps(_mm256_cmp_ps(a, amin, _CMP_GE_OQ), _mm256_cmp_ps(actp, zero, _CMP_NEQ_UQ)));
      const __m256 testT = _mm256_mul_ps(Tp, _mm256_sub_ps(one, a));
      const __m256 stop = _mm256_and_ps(ok, _mm256_cmp_ps(testT, tmin, _CMP_LT_OQ));
      const __m256 blend = _mm256_andnot_ps(stop, ok);
      const int bm = _mm256_movemask_ps(blend), sm = _mm256_movemask_ps(stop);
      blends += __builtin_popcount(unsigned(bm));
      if (sm) store8<P>(act + pg, _mm256_andnot_ps(stop, actp));
      if (!bm) return sm | cm;
      visited_blend |= 1u << bit;
      const __m256 wp = _mm256_and_ps(blend, _mm256_mul_ps(a, Tp));
      if constexpr (TRACK) {  // features-only calls (view selection) skip the depth bookkeeping
        const __m256 med = _mm256_and_ps(blend, _mm256_cmp_ps(Tp, half, _CMP_GT_OQ));
        store8<P>(medz + pg, _mm256_blendv_ps(load8<P>(medz + pg), z, med));
        float* mj = reinterpret_cast<float*>(medj + pg);
        store8<P>(mj, _mm256_blendv_ps(load8<P>(mj), vj, med));
        float* lj = reinterpret_cast<float*>(last + pg);
        store8<P>(lj, _mm256_blendv_ps(load8<P>(lj), vj1, blend));
      }
      store8<P>(T + pg, _mm256_blendv_ps(Tp, testT, blend));
      store8<P>(accA + pg, _mm256_add_ps(load8<P>(accA + pg), wp));
      for (int d = 0; d < D; ++d) {
        float* acc = &accF[size_t(d) * TP + pg];
        store8<P>(acc, _mm256_fmadd_ps(wp, _mm256_set1_ps(f[d]), load8<P>(acc)));
      }
      if (fl.normal)
        for (int c = 0; c < 3; ++c) {
          float* acc = &accN[size_t(c) * TP + pg];
          store8<P>(acc, _mm256_fmadd_ps(wp, _mm256_set1_ps(q[12 + c]), load8<P>(acc)));
        }
      if (dz) {
        const __m256 zs = _mm256_blendv_ps(vnear, z, blend);
        const __m256 m = _mm256_mul_ps(vmscale, _mm256_sub_ps(one, _mm256_div_ps(vnear, zs)));
        const __m256 wm = _mm256_mul_ps(wp, m);
        store8<P>(accZ + pg, _mm256_fmadd_ps(wp, zs, load8<P>(accZ + pg)));
        store8<P>(accM + pg, _mm256_add_ps(load8<P>(accM + pg), wm));
        store8<P>(accM2 + pg, _mm256_fmadd_ps(wm, m, load8<P>(accM2 + pg)));
      }
      return sm | cm;
    };
    // clears the live bits of the pixels of row r whose terminate bits are set in sm (4 or 8 bits)
    auto terminate = [&](int r, uint32_t sm, int c) {
      if (!sm) return;
      live[r] &= ~(sm << c);
      rows_alive -= live[r] == 0;
    };
    if (sp.pairs) {
      for (int p00 = sp.p0; p00 < sp.p1; p00 += 2 * RS) {  // the second row may be past the box
        const int r = p00 / RS;
        if ((((live[r] | live[r + 1]) >> sp.c0) & 0xfu) == 0) continue;  // its 8 pixels have terminated
        const RowVec rv = row_vec(row_of(M, py[p00], my), row_of(M, py[p00 + RS], my));
        const uint32_t sm = uint32_t(group(std::true_type{}, p00 + sp.c0, rv, group_bit(sp, p00, sp.c0)));
        terminate(r, sm & 0xfu, sp.c0);
        terminate(r + 1, sm >> 4, sp.c0);
      }
      if (out_blended) out_blended[jj] = visited_blend;
      continue;
    }
    for (int p00 = sp.p0; p00 < sp.p1; p00 += RS) {
      const int r = p00 / RS;
      if (live[r] == 0) continue;  // every pixel of this row has terminated
      const RowVec rv = row_vec(row_of(M, py[p00], my));
      for (int c = sp.c0; c < sp.c1; c += LANES) {
        if (((live[r] >> c) & 0xffu) == 0) continue;  // its 8 pixels have terminated
        terminate(r, uint32_t(group(std::false_type{}, p00 + c, rv, group_bit(sp, p00, c))), c);
      }
    }
    if (out_blended) out_blended[jj] = visited_blend;
  }
  return TileWork{evals, blends, left};
}
#endif

// The forward blend of one tile's splats for any S: per splat, its weights w over the rows its box
// covers (whole rows, so the feature, normal and depth sums below run branch-free over [p0, p1)),
// then those sums. A row whose pixels have all terminated is skipped; every CHUNK splats the tile
// stops when no row is left.
template <typename S, bool TRACK>
TileWork forward_splats_generic(FwdTile<S>& t, const Bins<S>& B, int D, const Settings& st, const Flags& fl) {
  const int tx = t.tx, ty = t.ty;
  const int64_t b0 = t.b0, b1 = t.b1;
  const S *px = t.px, *py = t.py;
  S *T = t.T, *act = t.act, *accA = t.accA, *accZ = t.accZ, *accM = t.accM, *accM2 = t.accM2, *medz = t.medz;
  int32_t *last = t.last, *medj = t.medj;
  std::vector<S>& accF = t.accF;
  std::vector<S>& accN = t.accN;
  const S near = S(st.near), mscale = S(st.far / (st.far - st.near));
  int64_t evals = 0, blends = 0;
  alignas(64) S w[TP], zz[TP];  // a splat's weight and depth at each pixel
  for (int p = 0; p < TP; ++p) {
    w[p] = S(0);
    zz[p] = S(st.near);
  }
  bool row_alive[TS];
  for (int r = 0; r < TS; ++r) row_alive[r] = ty * TS + r < st.H;
  const bool cut = !B.stop_T.empty();
  double left = 0;
  constexpr int CHUNK = 32;
  for (int64_t jj = b0; jj < b1; ++jj) {
    if (jj > b0 && ((jj - b0) % CHUNK) == 0 && std::none_of(row_alive, row_alive + TS, [](bool b) { return b; }))
      break;
    const int k = B.ids[jj];
    const S* q = &B.rec[size_t(k) * B.R];
    const Span sp = span_of(&B.rect[4 * size_t(k)], tx, ty);
    const int p0 = sp.p0, p1 = sp.p1;
    const S* M = q;
    const S mx = q[9], my = q[10], o = q[11];
    const int32_t j = int32_t(jj - b0);
    const int c0 = sp.c0, c1 = sp.c1;
    int any = 0;
    for (int p00 = p0; p00 < p1; p00 += RS) {
      if (!row_alive[p00 / RS]) {  // every pixel of this row has terminated
        for (int p = p00; p < p00 + RS; ++p) w[p] = S(0);
        continue;
      }
      const Row<S> rw = row_of(M, py[p00], my);
      for (int p = p00; p < p00 + RS; ++p) w[p] = S(0);
      if (cut) {  // the pixels the cut stops before this record (see Bins::stop_T)
        const S stop_T = B.stop_T[jj];
        S stopped = 0;
        for (int p = p00 + c0; p < p00 + c1; ++p) {
          const bool early = act[p] != 0 && T[p] < stop_T;
          stopped += early ? T[p] : S(0);
          act[p] = early ? S(0) : act[p];
        }
        left += double(stopped) * double(B.left_max[jj]);
      }
      evals += c1 - c0;
      for (int pg = p00 + c0; pg < p00 + c1; pg += LANES) {
#pragma omp simd reduction(| : any) reduction(+ : blends)
        for (int p = pg; p < pg + LANES; ++p) {
          const Hit<S> h = hit(M, rw, mx, o, px[p], near);
          const S testT = T[p] * (S(1) - h.a);
          const bool ok = h.ok && act[p] != 0;
          const bool stop = ok && testT < S(T_MIN);
          const bool blend = ok && !stop;
          const S wp = blend ? h.a * T[p] : S(0);
          w[p] = wp;
          if constexpr (TRACK) {  // features-only calls (view selection) skip the depth bookkeeping
            zz[p] = blend ? h.z : near;
            const bool med = blend && T[p] > S(0.5);
            medz[p] = med ? h.z : medz[p];
            medj[p] = med ? j : medj[p];
            last[p] = blend ? j + 1 : last[p];
          }
          T[p] = blend ? testT : T[p];
          act[p] = stop ? S(0) : act[p];
          accA[p] += wp;
          any |= int(blend);
          blends += int(blend);
        }
      }
      S alive = 0;
      for (int p = p00; p < p00 + TS; ++p) alive += act[p];
      row_alive[p00 / RS] = alive != 0;
    }
    if (!any) continue;
    for (int d = 0; d < D; ++d) {
      const S f = q[REC + d];
      S* acc = &accF[size_t(d) * TP];
#pragma omp simd
      for (int p = p0; p < p1; ++p) acc[p] += w[p] * f;
    }
    if (fl.normal)
      for (int k = 0; k < 3; ++k) {
        const S nk = q[12 + k];
        S* acc = &accN[size_t(k) * TP];
#pragma omp simd
        for (int p = p0; p < p1; ++p) acc[p] += w[p] * nk;
      }
    if (fl.depth || fl.dist) {
#pragma omp simd
      for (int p = p0; p < p1; ++p) {
        accZ[p] += w[p] * zz[p];
        const S m = mscale * (S(1) - near / zz[p]);
        accM[p] += w[p] * m;
        accM2[p] += w[p] * m * m;
      }
    }
  }
  return TileWork{evals, blends, left};
}

// A tile's sums into the images, at its pixels in the image.
template <typename S, bool TRACK>
void write_tile(const FwdTile<S>& t, int D, const Settings& st, const Flags& fl, const FwdOut<S>& out) {
  for (int p = 0; p < TP; ++p) {
    const SlotPixel sl = slot_pixel(p, t.tx, t.ty, st.W, st.H);
    if (!sl.in_image) continue;
    const int64_t q = int64_t(sl.y) * st.W + sl.x;
    for (int d = 0; d < D; ++d) out.feat[q * D + d] = t.accF[size_t(d) * TP + p];
    out.alpha[q] = t.accA[p];
    if (fl.normal)
      for (int k = 0; k < 3; ++k) out.normal[q * 3 + k] = t.accN[size_t(k) * TP + p];
    if (fl.depth || fl.dist) { out.zsum[q] = t.accZ[p]; out.msum[q] = t.accM[p]; out.m2sum[q] = t.accM2[p]; }
    if constexpr (TRACK) {
      out.median[q] = t.medz[p];
      out.last[q] = t.last[p];
      out.medj[q] = t.medj[p];
    }
  }
}

}  // namespace

template <typename S, bool TRACK>
TileWork forward_tile(int tile, const Bins<S>& B, int D, const Settings& st, const Flags& fl,
                      const FwdOut<S>& out) {
  FwdTile<S> t(tile, B, D, st, fl);
  TileWork work;
#if FR_AVX2
  if constexpr (std::is_same<S, float>::value) work = forward_splats_avx2<TRACK>(t, B, D, st, fl, out.blended);
  else
#endif
    work = forward_splats_generic<S, TRACK>(t, B, D, st, fl);
  write_tile<S, TRACK>(t, D, st, fl, out);
  return work;
}

template TileWork forward_tile<float, true>(int, const Bins<float>&, int, const Settings&, const Flags&,
                                            const FwdOut<float>&);
template TileWork forward_tile<float, false>(int, const Bins<float>&, int, const Settings&, const Flags&,
                                             const FwdOut<float>&);
template TileWork forward_tile<double, true>(int, const Bins<double>&, int, const Settings&, const Flags&,
                                             const FwdOut<double>&);
template TileWork forward_tile<double, false>(int, const Bins<double>&, int, const Settings&, const Flags&,
                                              const FwdOut<double>&);

namespace {

template <typename S>
std::vector<torch::Tensor> forward_impl(torch::Tensor means, torch::Tensor U, torch::Tensor V,
                                        torch::Tensor n, torch::Tensor opac, torch::Tensor feats,
                                        torch::Tensor viewmats, torch::Tensor Ks, int64_t W, int64_t H,
                                        double near, double far, const Flags& fl, const uint8_t* keep_tiles,
                                        RenderCache* cache) {
  const int64_t N = means.size(0), C = viewmats.size(0), D = feats.size(2);
  const bool shared = feats.size(0) == 1;
  const bool keep = cache != nullptr && C == 1;
  if (cache) cache->get<S>().reset();
  auto opt = means.options();
  // every output pixel and radius is written below (torch::empty: no zero fill of [C,H,W,..])
  auto feat_img = torch::empty({C, H, W, D}, opt);
  auto alpha = torch::empty({C, H, W}, opt);
  auto normal = torch::empty({fl.normal ? C : 0, H, W, 3}, opt);
  const bool dz = fl.depth || fl.dist;
  auto zsum = torch::empty({dz ? C : 0, H, W}, opt);
  auto msum = torch::empty({dz ? C : 0, H, W}, opt);
  auto m2sum = torch::empty({dz ? C : 0, H, W}, opt);
  const int64_t Ct = fl.track ? C : 0;
  auto median = torch::empty({Ct, H, W}, opt);
  auto iopt = opt.dtype(torch::kInt32);
  auto last = torch::empty({Ct, H, W}, iopt);
  auto medj = torch::empty({Ct, H, W}, iopt);
  auto radii = torch::empty({C, N}, iopt);
  const Settings st = settings_of(W, H, near, far);
  const int tiles = st.tiles_x * st.tiles_y;
  std::vector<Camera> cams;
  for (int64_t c = 0; c < C; ++c) cams.push_back(camera_of(viewmats, Ks, c));
  std::vector<Stats> per(C);
  const S *pm = means.data_ptr<S>(), *pu = U.data_ptr<S>(), *pv = V.data_ptr<S>(), *pn = n.data_ptr<S>();
  const double tc = omp_get_wtime();
  // The Morton sort pays when several cameras share it; one camera (the mapper's renders) sees
  // much of the map, and its splats are projected in id order as before.
  const SplatGroups<S> groups = group_splats(pm, pu, pv, pn, opac.data_ptr<S>(), N, C > 1);
  const double groups_s = omp_get_wtime() - tc;
  // One camera: project, bin, sort, blend. Its inner parallel loops run serially when called from
  // the camera-parallel region below (nested parallelism is off), in parallel otherwise.
  auto one = [&](int64_t c, Projected<S>& P, Visible& vis, Bins<S>* kept_bins) {
    Stats& sc = per[c];
    double t0 = omp_get_wtime();
    project_camera<S>(groups, cams[c], st, P, vis);
    write_radii(groups, vis, P, radii.data_ptr<int32_t>() + c * N);
    sc.project += omp_get_wtime() - t0;
    const S* f = feats.data_ptr<S>() + (shared ? 0 : c * N * D);
    Bins<S> B = bin_and_sort(P, groups, vis, f, int(D), st, sc, keep_tiles ? keep_tiles + c * tiles : nullptr);
    if (kept_bins && FR_AVX2 && std::is_same<S, float>::value) B.blended.assign(B.ids.size(), 0u);
    const int64_t HW = H * W;
    FwdOut<S> out{feat_img.data_ptr<S>() + c * HW * D, alpha.data_ptr<S>() + c * HW,
                  fl.normal ? normal.data_ptr<S>() + c * HW * 3 : nullptr,
                  dz ? zsum.data_ptr<S>() + c * HW : nullptr, dz ? msum.data_ptr<S>() + c * HW : nullptr,
                  dz ? m2sum.data_ptr<S>() + c * HW : nullptr, fl.track ? median.data_ptr<S>() + c * HW : nullptr,
                  fl.track ? last.data_ptr<int32_t>() + c * HW : nullptr,
                  fl.track ? medj.data_ptr<int32_t>() + c * HW : nullptr,
                  B.blended.empty() ? nullptr : B.blended.data()};
    t0 = omp_get_wtime();
    int64_t evals = 0, blends = 0;
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : evals, blends)
    for (int t = 0; t < tiles; ++t) {
      const TileWork tw = fl.track ? forward_tile<S, true>(t, B, int(D), st, fl, out)
                                   : forward_tile<S, false>(t, B, int(D), st, fl, out);
      evals += tw.evals;
      blends += tw.blends;
    }
    sc.blend += omp_get_wtime() - t0;
    sc.evals += evals;
    sc.blends += blends;
    if (kept_bins) *kept_bins = std::move(B);
  };
  // Many cameras (view selection): a whole camera per thread, so no per-camera fork/join; each
  // camera's result is computed by the same code either way, so batched == single calls exactly.
  const bool by_camera = C > 1 && C >= omp_get_max_threads();
  if (by_camera) {
#pragma omp parallel
    {
      Projected<S> P(N);
      Visible vis;
#pragma omp for schedule(dynamic, 1)
      for (int64_t c = 0; c < C; ++c) one(c, P, vis, nullptr);
    }
  } else {
    Projected<S> P(N);
    Visible vis;
    Bins<S> B;
    for (int64_t c = 0; c < C; ++c) one(c, P, vis, keep ? &B : nullptr);
    if (keep)
      cache->get<S>().reset(new KeptCamera<S>{std::move(P), std::move(B), N, D, W, H, near, far, cams[0]});
  }
  g_stats = Stats();
  g_stats.by_camera = by_camera;
  for (const Stats& sc : per) g_stats.add(sc);
  g_stats.project += groups_s;
  return {feat_img, alpha, normal, zsum, msum, m2sum, median, last, medj, radii};
}

}  // namespace

std::vector<torch::Tensor> forward(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                   torch::Tensor opac, torch::Tensor feats, torch::Tensor viewmats,
                                   torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                   bool normal, bool depth, bool dist, bool track, torch::Tensor keep_tiles,
                                   RenderCache* cache) {
  const Flags fl{normal, depth, dist, track || normal || depth || dist};
  const uint8_t* keep = tile_flags(keep_tiles, viewmats.size(0), W, H);
  if (means.scalar_type() == torch::kFloat64)
    return forward_impl<double>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, keep, cache);
  return forward_impl<float>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, keep, cache);
}

}  // namespace raster

// Backward blend of the rasterizer: the analytic gradients of the forward's images. Per tile, its
// splats are retraced front to back up to each pixel's last blended one (the forward's `last`), and
// each (tile, splat) pair's gradient terms go into a slot of their own; the slots are then reduced
// per splat in tile order (reduce_slots) and taken through the projection to the splats' parameters
// (chain_to_splats). backward_tile sets up a tile's pixels; the splat loop has two twins:
// backward_splats_avx2 (float, AVX2 registers) and backward_splats_generic (any S, and the Fisher
// mode of rasterize_fisher.cpp), with the same arithmetic per pixel.
#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

#include "rasterize_blend.h"
#include "rasterize_torch.h"

namespace raster {
namespace {

template <typename S>
struct BwdIn {
  const S *feat, *alpha, *normal, *zsum, *msum, *m2sum;          // forward outputs
  const int32_t *last, *medj;
  const S *gF, *gA, *gN, *gZ, *gM, *gM2, *gMed;                   // upstream gradients
};

// One tile's pixels, by slot (TP, slot_pixel): the forward's outputs and the upstream gradients the
// splat loops read, and the transmittance T and the part Pre of the total Tot (the upstream
// gradient dotted with the tile's blended outputs) that the splats before the current one gave.
template <typename S>
struct BwdTile {
  int tx, ty;
  int64_t b0;                     // the tile's records start at B.ids[b0], in depth order
  int maxlast = 0;                // splats [0, maxlast) of the tile blend at some pixel
  int32_t row_last[TS + 1] = {};  // the same per row; the padding row's is 0
  alignas(64) S px[TP], py[TP], T[TP], Pre[TP], Tot[TP];
  alignas(64) S gA[TP], gZ[TP], gM[TP], gM2[TP], gMed[TP];
  alignas(64) int32_t last[TP], medj[TP];
  std::vector<S> gF, gN;  // [D][TP], [3][TP]
  BwdTile(int tile, const Bins<S>& B, int D, const Settings& st, const Flags& fl, const BwdIn<S>& in)
      : tx(tile % st.tiles_x), ty(tile / st.tiles_x), b0(B.offsets[tile]), gF(size_t(D) * TP, S(0)),
        gN(3 * TP, S(0)) {
    for (int p = 0; p < TP; ++p) {
      const SlotPixel sl = slot_pixel(p, tx, ty, st.W, st.H);
      px[p] = S(sl.x) + S(0.5);
      py[p] = S(sl.y) + S(0.5);
      T[p] = S(1);
      Pre[p] = S(0);
      gA[p] = gZ[p] = gM[p] = gM2[p] = gMed[p] = Tot[p] = S(0);
      last[p] = 0;
      medj[p] = -1;
      if (!sl.in_image) continue;
      const int64_t q = int64_t(sl.y) * st.W + sl.x;
      S tot = 0;
      for (int d = 0; d < D; ++d) {
        gF[size_t(d) * TP + p] = in.gF[q * D + d];
        tot += in.gF[q * D + d] * in.feat[q * D + d];
      }
      gA[p] = in.gA[q];
      tot += gA[p] * in.alpha[q];
      if (fl.normal)
        for (int k = 0; k < 3; ++k) {
          gN[size_t(k) * TP + p] = in.gN[q * 3 + k];
          tot += in.gN[q * 3 + k] * in.normal[q * 3 + k];
        }
      if (fl.depth || fl.dist) {
        gZ[p] = in.gZ[q]; gM[p] = in.gM[q]; gM2[p] = in.gM2[q];
        tot += gZ[p] * in.zsum[q] + gM[p] * in.msum[q] + gM2[p] * in.m2sum[q];
      }
      gMed[p] = in.gMed[q];
      Tot[p] = tot;
      last[p] = in.last[q];
      medj[p] = in.medj[q];
      maxlast = std::max(maxlast, last[p]);
    }
    for (int r = 0; r < TS; ++r) row_last[r] = *std::max_element(last + r * RS, last + r * RS + TS);
  }
};

#if FR_AVX2
constexpr int MAX_D_AVX2 = 16;  // feature widths up to this keep their sums in registers

inline float hsum8(__m256 v) {
  __m128 s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
  s = _mm_add_ps(s, _mm_movehl_ps(s, s));
  s = _mm_add_ss(s, _mm_movehdup_ps(s));
  return _mm_cvtss_f32(s);
}

// A group's row values for the backward: those of `hit8` and the row's l, y and y - my; for a 4x2
// group, rows ya (lanes 0-3) and yb (lanes 4-7).
struct RowB {
  RowVec rv;
  __m256 l0, l1, l2, y, dyc;
};
inline RowB row_b(const float* M, float y, float my) {
  const Row<float> a = row_of(M, y, my);
  return {row_vec(a), _mm256_set1_ps(a.l0), _mm256_set1_ps(a.l1), _mm256_set1_ps(a.l2), _mm256_set1_ps(y),
          _mm256_set1_ps(y - my)};
}
inline RowB row_b(const float* M, float ya, float yb, float my) {
  const Row<float> a = row_of(M, ya, my), b = row_of(M, yb, my);
  return {row_vec(a, b), halves(a.l0, b.l0), halves(a.l1, b.l1), halves(a.l2, b.l2), halves(ya, yb),
          halves(ya - my, yb - my)};
}

// The backward blend of one tile's splats for float (not the Fisher mode): the per-pixel
// arithmetic of backward_splats_generic in AVX2 registers, with each splat's per-pixel gradient
// terms summed in 8-lane registers over the groups it covers (one horizontal sum per slot entry at
// the end) instead of being stored per pixel and reduced over whole box rows.
void backward_splats_avx2(BwdTile<float>& t, const Bins<float>& B, int D, const Flags& fl, int G, float* slots,
                          const Settings& st) {
  const int tx = t.tx, ty = t.ty, maxlast = t.maxlast;
  const int64_t b0 = t.b0;
  const int32_t* row_last = t.row_last;
  const float *px = t.px, *py = t.py, *Tot = t.Tot;
  float *T = t.T, *Pre = t.Pre;
  const float *gA = t.gA, *gZ = t.gZ, *gM = t.gM, *gM2 = t.gM2, *gMed = t.gMed;
  const int32_t *last = t.last, *medj = t.medj;
  const float *gF = t.gF.data(), *gN = t.gN.data();
  const float nearf = float(st.near);
  const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f), vnear = _mm256_set1_ps(nearf);
  const __m256 amax = _mm256_set1_ps(float(ALPHA_MAX)), amin = _mm256_set1_ps(float(ALPHA_MIN));
  const __m256 vmscale = _mm256_set1_ps(float(st.far / (st.far - st.near)));
  const __m256 vmder = _mm256_set1_ps(float(st.far * st.near / (st.far - st.near)));
  const __m256 two = _mm256_set1_ps(2.0f), mhalf = _mm256_set1_ps(-0.5f);
  const __m256 fm2 = _mm256_set1_ps(float(FILTER_INV_SQ) * -2.0f);
  const bool dz = fl.depth || fl.dist;
  constexpr int AHEAD = 4;
  for (int32_t j = 0; j < maxlast; ++j) {
    const int64_t jj = b0 + j;
    if (j + AHEAD < maxlast) {
      const char* nx = reinterpret_cast<const char*>(&B.rec[size_t(B.ids[jj + AHEAD]) * B.R]);
      _mm_prefetch(nx, _MM_HINT_T0);
      _mm_prefetch(nx + 60, _MM_HINT_T0);
    }
    float* slot = slots + jj * G;
    const int k = B.ids[jj];
    const float* q = &B.rec[size_t(k) * B.R];
    const Span sp = span_of(&B.rect[4 * size_t(k)], tx, ty);
    const float* M = q;
    const float mx = q[9], my = q[10], o = q[11];
    const float* f = q + REC;
    const __m256 vmx = _mm256_set1_ps(mx), vo = _mm256_set1_ps(o);
    const __m256 m0 = _mm256_set1_ps(M[0]), m1 = _mm256_set1_ps(M[1]), m2 = _mm256_set1_ps(M[2]);
    const __m256 m6 = _mm256_set1_ps(M[6]), m7 = _mm256_set1_ps(M[7]), m8 = _mm256_set1_ps(M[8]);
    const __m256i vj = _mm256_set1_epi32(j);
    // the groups in which the forward blended this record (all when it did not record them)
    const uint32_t blended = B.blended.empty() ? ~0u : B.blended[jj];
    if (blended == 0) continue;  // its slot stays 0, as the sums of groups that all return early
    __m256 acc[NG], accO = zero, accN[3] = {zero, zero, zero}, accF[MAX_D_AVX2];
    for (int e = 0; e < NG; ++e) acc[e] = zero;
    for (int d = 0; d < D; ++d) accF[d] = zero;
    // One group at slot pg (see load8): its terms go into the splat's 8-lane sums.
    auto group = [&](auto pair, int pg, const RowB& rb) {
      constexpr bool P = decltype(pair)::value;
      const __m256 x = load8<P>(px + pg);
      const Hit8 h = hit8(x, rb.rv, vmx, m6, m7, m8);
      const __m256 l0 = rb.l0, l1 = rb.l1, l2 = rb.l2, y = rb.y, dyc = rb.dyc;
      const __m256 nz = h.nz, inv = h.inv, u = h.u, v = h.v, dx = h.dx, use3 = h.use3, z = h.z, g = h.g;
      const __m256 og = _mm256_mul_ps(vo, g);
      const __m256 ah = _mm256_min_ps(amax, og);
      const __m256 lastp = _mm256_castsi256_ps(_mm256_cmpgt_epi32(load8i<P>(last + pg), vj));
      const __m256 blend = _mm256_and_ps(
          _mm256_and_ps(nz, _mm256_cmp_ps(z, vnear, _CMP_GE_OQ)), _mm256_and_ps(_mm256_cmp_ps(ah, amin, _CMP_GE_OQ), lastp));
      const __m256i medm = _mm256_cmpeq_epi32(load8i<P>(medj + pg), vj);
      if (_mm256_movemask_ps(blend) == 0 && _mm256_testz_si256(medm, medm)) return;  // all terms are 0
      const __m256 a = _mm256_and_ps(blend, ah);
      const __m256 zs = _mm256_blendv_ps(vnear, z, blend);
      const __m256 Tp = load8<P>(T + pg);
      const __m256 wp = _mm256_mul_ps(a, Tp);
      __m256 sf = load8<P>(gA + pg);
      for (int d = 0; d < D; ++d) sf = _mm256_fmadd_ps(_mm256_set1_ps(f[d]), load8<P>(gF + size_t(d) * TP + pg), sf);
      if (fl.normal)
        for (int c = 0; c < 3; ++c) sf = _mm256_fmadd_ps(_mm256_set1_ps(q[12 + c]), load8<P>(gN + size_t(c) * TP + pg), sf);
      __m256 dzv = _mm256_and_ps(_mm256_castsi256_ps(medm), load8<P>(gMed + pg));
      if (dz) {
        const __m256 m = _mm256_mul_ps(vmscale, _mm256_sub_ps(one, _mm256_div_ps(vnear, zs)));
        const __m256 dm = _mm256_div_ps(vmder, _mm256_mul_ps(zs, zs));
        const __m256 gz = load8<P>(gZ + pg), gm = load8<P>(gM + pg), gm2 = load8<P>(gM2 + pg);
        sf = _mm256_fmadd_ps(gz, zs, sf);
        sf = _mm256_fmadd_ps(gm, m, sf);
        sf = _mm256_fmadd_ps(_mm256_mul_ps(gm2, m), m, sf);
        const __m256 inner = _mm256_fmadd_ps(_mm256_mul_ps(_mm256_mul_ps(gm2, two), m), dm, _mm256_fmadd_ps(gm, dm, gz));
        dzv = _mm256_fmadd_ps(wp, inner, dzv);
      }
      const __m256 pre = _mm256_fmadd_ps(wp, sf, load8<P>(Pre + pg));
      store8<P>(Pre + pg, pre);
      const __m256 rest = _mm256_sub_ps(load8<P>(Tot + pg), pre);
      const __m256 dA = _mm256_sub_ps(_mm256_mul_ps(Tp, sf), _mm256_div_ps(rest, _mm256_sub_ps(one, a)));
      const __m256 free_a = _mm256_and_ps(blend, _mm256_cmp_ps(og, amax, _CMP_LT_OQ));
      const __m256 dOp = _mm256_and_ps(free_a, _mm256_mul_ps(dA, g));
      const __m256 drho = _mm256_and_ps(free_a, _mm256_mul_ps(_mm256_mul_ps(mhalf, dA), a));
      const __m256 dzu = _mm256_and_ps(use3, dzv);
      const __m256 d2 = _mm256_mul_ps(drho, two);
      const __m256 du = _mm256_fmadd_ps(m6, dzu, _mm256_and_ps(use3, _mm256_mul_ps(d2, u)));
      const __m256 dv = _mm256_fmadd_ps(m7, dzu, _mm256_and_ps(use3, _mm256_mul_ps(d2, v)));
      const __m256 df = _mm256_andnot_ps(use3, _mm256_mul_ps(drho, fm2));
      const __m256 dmx = _mm256_mul_ps(df, dx), dmy = _mm256_mul_ps(df, dyc);
      const __m256 dq0 = _mm256_mul_ps(du, inv), dq1 = _mm256_mul_ps(dv, inv);
      const __m256 dq2 = _mm256_mul_ps(_mm256_sub_ps(zero, _mm256_fmadd_ps(du, u, _mm256_mul_ps(dv, v))), inv);
      const __m256 k0 = _mm256_fmsub_ps(x, m6, m0), k1 = _mm256_fmsub_ps(x, m7, m1), k2 = _mm256_fmsub_ps(x, m8, m2);
      // q = k x l: dk = l x dq, dl = dq x k
      const __m256 dk0 = _mm256_fmsub_ps(l1, dq2, _mm256_mul_ps(l2, dq1));
      const __m256 dk1 = _mm256_fmsub_ps(l2, dq0, _mm256_mul_ps(l0, dq2));
      const __m256 dk2 = _mm256_fmsub_ps(l0, dq1, _mm256_mul_ps(l1, dq0));
      const __m256 dl0 = _mm256_fmsub_ps(dq1, k2, _mm256_mul_ps(dq2, k1));
      const __m256 dl1 = _mm256_fmsub_ps(dq2, k0, _mm256_mul_ps(dq0, k2));
      const __m256 dl2 = _mm256_fmsub_ps(dq0, k1, _mm256_mul_ps(dq1, k0));
      acc[0] = _mm256_sub_ps(acc[0], dk0);
      acc[1] = _mm256_sub_ps(acc[1], dk1);
      acc[2] = _mm256_sub_ps(acc[2], dk2);
      acc[3] = _mm256_sub_ps(acc[3], dl0);
      acc[4] = _mm256_sub_ps(acc[4], dl1);
      acc[5] = _mm256_sub_ps(acc[5], dl2);
      acc[6] = _mm256_add_ps(acc[6], _mm256_fmadd_ps(x, dk0, _mm256_fmadd_ps(y, dl0, _mm256_mul_ps(u, dzu))));
      acc[7] = _mm256_add_ps(acc[7], _mm256_fmadd_ps(x, dk1, _mm256_fmadd_ps(y, dl1, _mm256_mul_ps(v, dzu))));
      acc[8] = _mm256_add_ps(acc[8], _mm256_fmadd_ps(x, dk2, _mm256_fmadd_ps(y, dl2, dzv)));
      acc[9] = _mm256_add_ps(acc[9], dmx);
      acc[10] = _mm256_add_ps(acc[10], dmy);
      accO = _mm256_add_ps(accO, dOp);
      if (fl.normal)
        for (int c = 0; c < 3; ++c) accN[c] = _mm256_fmadd_ps(wp, load8<P>(gN + size_t(c) * TP + pg), accN[c]);
      for (int d = 0; d < D; ++d) accF[d] = _mm256_fmadd_ps(wp, load8<P>(gF + size_t(d) * TP + pg), accF[d]);
      store8<P>(T + pg, _mm256_mul_ps(Tp, _mm256_sub_ps(one, a)));
    };
    if (sp.pairs) {
      for (int p00 = sp.p0; p00 < sp.p1; p00 += 2 * RS) {  // the second row may be past the box
        const int r = p00 / RS;
        if (j >= row_last[r] && j >= row_last[r + 1]) continue;
        if (!((blended >> group_bit(sp, p00, sp.c0)) & 1u)) continue;  // no pixel of the group blends
        group(std::true_type{}, p00 + sp.c0, row_b(M, py[p00], py[p00 + RS], my));
      }
    } else {
      for (int p00 = sp.p0; p00 < sp.p1; p00 += RS) {
        if (j >= row_last[p00 / RS]) continue;  // no pixel of this row blends this splat or any later one
        if (!((blended >> group_bit(sp, p00, sp.c0)) & 3u)) continue;  // neither group of the row blends
        const RowB rb = row_b(M, py[p00], my);
        for (int c = sp.c0; c < sp.c1; c += LANES)
          if ((blended >> group_bit(sp, p00, c)) & 1u) group(std::false_type{}, p00 + c, rb);
      }
    }
    for (int e = 0; e < NG; ++e) slot[e] = hsum8(acc[e]);
    slot[NG] = hsum8(accO);
    if (fl.normal)
      for (int c = 0; c < 3; ++c) slot[NG + 1 + c] = hsum8(accN[c]);
    for (int d = 0; d < D; ++d) slot[NG + 4 + d] = hsum8(accF[d]);
  }
}
#endif

// The backward blend of one tile's splats for any S: per splat, its per-pixel gradient terms over
// the rows its box covers (whole rows: a row no pixel of which blends this splat or a later one is
// zeroed), then their sums over [p0, p1) into the splat's slot; in Fisher mode the slot takes the
// sums of their products instead (fisher_slot).
template <typename S, bool FISHER>
void backward_splats_generic(BwdTile<S>& t, const Bins<S>& B, int D, const Flags& fl, int G, S* slots,
                             const Settings& st) {
  const int tx = t.tx, ty = t.ty, maxlast = t.maxlast;
  const int64_t b0 = t.b0;
  const int32_t* row_last = t.row_last;
  const S *px = t.px, *py = t.py, *Tot = t.Tot;
  S *T = t.T, *Pre = t.Pre;
  const S *gA = t.gA, *gZ = t.gZ, *gM = t.gM, *gM2 = t.gM2, *gMed = t.gMed;
  const int32_t *last = t.last, *medj = t.medj;
  const std::vector<S>& gF = t.gF;
  const std::vector<S>& gN = t.gN;
  alignas(64) S s[TP], w[TP];  // a splat's upstream gradient dotted with its values, and its weight
  alignas(64) S gg[NG][TP];    // its geometric gradient terms
  const S near = S(st.near), mscale = S(st.far / (st.far - st.near));
  const S mder = S(st.far * st.near / (st.far - st.near));
  for (int32_t j = 0; j < maxlast; ++j) {
    const int64_t jj = b0 + j;
    S* slot = slots + jj * G;
    const int k = B.ids[jj];
    const S* q = &B.rec[size_t(k) * B.R];
    const Span sp = span_of(&B.rect[4 * size_t(k)], tx, ty);
    const int p0 = sp.p0, p1 = sp.p1;
    const S* M = q;
    const S mx = q[9], my = q[10], o = q[11];
    const S* f = q + REC;
    const S* nr = q + 12;
    const int c0 = sp.c0, c1 = sp.c1;
#pragma omp simd
    for (int p = p0; p < p1; ++p) s[p] = gA[p];
    for (int d = 0; d < D; ++d) {
      const S fd = f[d];
      const S* g = &gF[size_t(d) * TP];
#pragma omp simd
      for (int p = p0; p < p1; ++p) s[p] += fd * g[p];
    }
    if (fl.normal)
      for (int k = 0; k < 3; ++k) {
        const S nk = nr[k];
        const S* g = &gN[size_t(k) * TP];
#pragma omp simd
        for (int p = p0; p < p1; ++p) s[p] += nk * g[p];
      }
    S dO = 0, o2 = 0, w2 = 0;
    for (int p00 = p0; p00 < p1; p00 += RS) {
      if (j >= row_last[p00 / RS]) {  // no pixel of this row blends this splat or any later one
        for (int p = p00; p < p00 + RS; ++p) {
          w[p] = S(0);
          for (int e = 0; e < NG; ++e) gg[e][p] = S(0);
        }
        continue;
      }
      const Row<S> rw = row_of(M, py[p00], my);
      for (int p = p00; p < p00 + RS; ++p) {
        w[p] = S(0);
        for (int e = 0; e < NG; ++e) gg[e][p] = S(0);
      }
      for (int pg = p00 + c0; pg < p00 + c1; pg += LANES) {
#pragma omp simd reduction(+ : dO, o2, w2)
        for (int p = pg; p < pg + LANES; ++p) {
          const Hit<S> h = hit(M, rw, mx, o, px[p], near);
          const bool blend = h.ok && j < last[p];
          const S a = blend ? h.a : S(0);
          const S zs = blend ? h.z : near;
          const S m = mscale * (S(1) - near / zs);
          const S dm = mder / (zs * zs);
          const S wp = a * T[p];
          const S sf = s[p] + gZ[p] * zs + gM[p] * m + gM2[p] * m * m;
          Pre[p] += wp * sf;
          const S Rest = Tot[p] - Pre[p];
          const S dA = T[p] * sf - Rest / (S(1) - a);
          const S dz = wp * (gZ[p] + gM[p] * dm + gM2[p] * S(2) * m * dm) + (j == medj[p] ? gMed[p] : S(0));
          const bool free_a = blend && o * h.g < S(ALPHA_MAX);
          const S dOp = free_a ? dA * h.g : S(0);
          const S drho = free_a ? S(-0.5) * dA * a : S(0);
          const bool use3 = h.use3;
          const S dzu = use3 ? dz : S(0);
          const S du = (use3 ? drho * S(2) * h.u : S(0)) + M[6] * dzu;
          const S dv = (use3 ? drho * S(2) * h.v : S(0)) + M[7] * dzu;
          const S dmx = use3 ? S(0) : drho * S(FILTER_INV_SQ) * S(-2) * (px[p] - mx);
          const S dmy = use3 ? S(0) : drho * S(FILTER_INV_SQ) * S(-2) * (py[p] - my);
          const S inv = S(1) / (h.q2 != 0 ? h.q2 : S(1));
          const S dq0 = du * inv, dq1 = dv * inv, dq2 = -(du * h.u + dv * h.v) * inv;
          const S x = px[p], y = py[p];
          const S k0 = x * M[6] - M[0], k1 = x * M[7] - M[1], k2 = x * M[8] - M[2];
          const S l0 = rw.l0, l1 = rw.l1, l2 = rw.l2;
          // q = k x l: dk = l x dq, dl = dq x k
          const S dk0 = l1 * dq2 - l2 * dq1, dk1 = l2 * dq0 - l0 * dq2, dk2 = l0 * dq1 - l1 * dq0;
          const S dl0 = dq1 * k2 - dq2 * k1, dl1 = dq2 * k0 - dq0 * k2, dl2 = dq0 * k1 - dq1 * k0;
          gg[0][p] = -dk0; gg[1][p] = -dk1; gg[2][p] = -dk2;
          gg[3][p] = -dl0; gg[4][p] = -dl1; gg[5][p] = -dl2;
          gg[6][p] = x * dk0 + y * dl0 + h.u * dzu;
          gg[7][p] = x * dk1 + y * dl1 + h.v * dzu;
          gg[8][p] = x * dk2 + y * dl2 + dz;
          gg[9][p] = dmx;
          gg[10][p] = dmy;
          dO += dOp;
          o2 += dOp * dOp;
          w2 += wp * wp;
          w[p] = wp;
          T[p] = blend ? T[p] * (S(1) - a) : T[p];
        }
      }
    }
    if (FISHER) {
      fisher_slot<S>(gg, p0, p1, o2, w2, slot);
      continue;
    }
    for (int e = 0; e < NG; ++e) {
      S acc = 0;
#pragma omp simd reduction(+ : acc)
      for (int p = p0; p < p1; ++p) acc += gg[e][p];
      slot[e] = acc;
    }
    slot[NG] = dO;
    if (fl.normal)
      for (int k = 0; k < 3; ++k) {
        const S* g = &gN[size_t(k) * TP];
        S acc = 0;
#pragma omp simd reduction(+ : acc)
        for (int p = p0; p < p1; ++p) acc += w[p] * g[p];
        slot[NG + 1 + k] = acc;
      }
    for (int d = 0; d < D; ++d) {
      const S* g = &gF[size_t(d) * TP];
      S acc = 0;
#pragma omp simd reduction(+ : acc)
      for (int p = p0; p < p1; ++p) acc += w[p] * g[p];
      slot[NG + 4 + d] = acc;
    }
  }
}

// Slot layout per (tile, splat): geometric 11 (T_u, T_v, T_w, means2d), opacity, normal 3, feat D.
// In Fisher mode: NSYM outer-product entries, sum of dL/do^2, sum of w^2 (rasterize_fisher.cpp).
template <typename S, bool FISHER>
void backward_tile(int tile, const Bins<S>& B, int D, const Settings& st, const Flags& fl,
                   const BwdIn<S>& in, int G, S* slots) {
  BwdTile<S> t(tile, B, D, st, fl, in);
#if FR_AVX2
  if constexpr (std::is_same<S, float>::value && !FISHER) {
    if (D <= MAX_D_AVX2) {
      backward_splats_avx2(t, B, D, fl, G, slots, st);
      return;
    }
  }
#endif
  backward_splats_generic<S, FISHER>(t, B, D, fl, G, slots, st);
}

// Sums each record's (binned splat's) slots in tile order into rows [records, G] (parallel over
// records): only binned splats have slots, so the rows leave out the rest of the map.
template <typename S>
std::vector<S> reduce_slots(const Bins<S>& B, int G, const std::vector<S>& slots) {
  const int64_t nis = int64_t(B.ids.size()), nrec = int64_t(B.splat.size());
  std::vector<int64_t> start(nrec + 1, 0);
  for (int64_t e = 0; e < nis; ++e) ++start[B.ids[e] + 1];
  for (int64_t r = 0; r < nrec; ++r) start[r + 1] += start[r];
  std::vector<int64_t> order(nis), fill(start.begin(), start.end() - 1);
  for (int64_t e = 0; e < nis; ++e) order[fill[B.ids[e]]++] = e;  // in tile order per record
  std::vector<S> rows(size_t(nrec) * G, S(0));
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < nrec; ++r)
    for (int64_t k = start[r]; k < start[r + 1]; ++k) {
      const S* src = &slots[size_t(order[k]) * G];
      S* dst = &rows[size_t(r) * G];
      for (int g = 0; g < G; ++g) dst[g] += src[g];
    }
  return rows;
}

// Gradient w.r.t. (T_u, T_v, T_w) including the path through means2d (the conic center).
template <typename S>
void geometric_to_M(const S* M, const S* g11, S mx, S my, S* gM) {
  const S tw0 = M[6], tw1 = M[7], tw2 = M[8];
  S d = tw0 * tw0 + tw1 * tw1 - tw2 * tw2;
  if (d == 0) d = S(-1e-30);
  const S gmx = g11[9], gmy = g11[10];
  const S twt[3] = {tw0, tw1, -tw2};
  const S tut[3] = {M[0], M[1], -M[2]}, tvt[3] = {M[3], M[4], -M[5]};
  for (int k = 0; k < 9; ++k) gM[k] = g11[k];
  for (int k = 0; k < 3; ++k) {
    gM[k] += gmx * twt[k] / d;
    gM[3 + k] += gmy * twt[k] / d;
    gM[6 + k] += (gmx * (tut[k] - S(2) * mx * twt[k]) + gmy * (tvt[k] - S(2) * my * twt[k])) / d;
  }
}

// Where chain_to_splats adds one camera's gradients: by splat id, [N, 3] each but opac [N] and
// feat [N, D].
template <typename S>
struct SplatGrads {
  S *means, *U, *V, *n, *opac, *feat;
};

// One camera's reduced rows through the projection to the splats' parameters: means2d and the ray
// transform M = K [U_c V_c p_c] to the camera-frame columns, then to the world frame (R^T).
template <typename S>
void chain_to_splats(const Projected<S>& P, const Bins<S>& B, const std::vector<S>& rows, int G, int64_t N,
                     int64_t D, const Camera& cam, const Flags& fl, const SplatGrads<S>& out) {
  S *gm = out.means, *gu = out.U, *gv = out.V, *gn = out.n, *go = out.opac, *gf = out.feat;
  const int64_t nrec = int64_t(B.splat.size());
  // splat i is at position i (groups in id order, no culling: every rect is this camera's); a
  // splat with a rect is binned, and its row is its record's
  std::unique_ptr<int32_t[]> rec_of(new int32_t[size_t(N)]);
  for (int64_t r = 0; r < nrec; ++r) rec_of[B.splat[r]] = int32_t(r);
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < N; ++i) {
    const int* r = &P.rect[4 * i];
    if (r[0] > r[2] || r[1] > r[3]) continue;
    const S* row = &rows[size_t(rec_of[i]) * G];
    S gM[9];
    geometric_to_M(&P.M[9 * i], row, P.m2d[2 * i], P.m2d[2 * i + 1], gM);
    // M = K [U_c V_c p_c]  ->  d cols = K^T dM; columns are U_c, V_c, p_c.
    S gcol[3][3];
    for (int jrow = 0; jrow < 3; ++jrow)
      for (int col = 0; col < 3; ++col)
        gcol[jrow][col] = S(cam.K[jrow]) * gM[col] + S(cam.K[3 + jrow]) * gM[3 + col] + S(cam.K[6 + jrow]) * gM[6 + col];
    for (int k = 0; k < 3; ++k) {
      // world = R^T camera
      S su = 0, sv = 0, sp = 0, sn = 0;
      for (int jrow = 0; jrow < 3; ++jrow) {
        const S Rjk = S(cam.R[3 * jrow + k]);
        su += Rjk * gcol[jrow][0];
        sv += Rjk * gcol[jrow][1];
        sp += Rjk * gcol[jrow][2];
        if (fl.normal) sn += Rjk * row[NG + 1 + jrow];
      }
      gu[3 * i + k] += su;
      gv[3 * i + k] += sv;
      gm[3 * i + k] += sp;
      gn[3 * i + k] += P.sign[i] * sn;
    }
    go[i] += row[NG];
    for (int d = 0; d < D; ++d) gf[i * D + d] += row[NG + 4 + d];
  }
}

template <typename S>
std::vector<torch::Tensor> backward_impl(torch::Tensor means, torch::Tensor U, torch::Tensor V,
                                         torch::Tensor n, torch::Tensor opac, torch::Tensor feats,
                                         torch::Tensor viewmats, torch::Tensor Ks, int64_t W, int64_t H,
                                         double near, double far, const Flags& fl,
                                         std::vector<torch::Tensor> fwd, std::vector<torch::Tensor> grads,
                                         bool fisher, const uint8_t* keep_tiles, RenderCache* cache) {
  const int64_t N = means.size(0), C = viewmats.size(0), D = feats.size(2);
  const bool shared = feats.size(0) == 1 && C > 1;
  auto opt = means.options();
  auto g_means = torch::zeros({N, 3}, opt), g_U = torch::zeros({N, 3}, opt);
  auto g_V = torch::zeros({N, 3}, opt), g_n = torch::zeros({N, 3}, opt);
  auto g_op = torch::zeros({N}, opt), g_feat = torch::zeros_like(feats);
  auto fis_geo = torch::zeros({fisher ? C : 0, N, NSYM}, opt);
  auto fis_o = torch::zeros({fisher ? C : 0, N}, opt), fis_w = torch::zeros({fisher ? C : 0, N}, opt);
  const Settings st = settings_of(W, H, near, far);
  const int tiles = st.tiles_x * st.tiles_y;
  const int G = fisher ? NSYM + 2 : NG + 4 + int(D);
  const int64_t HW = H * W;
  const bool dz = fl.depth || fl.dist;
  // The forward's projection and bins of a single camera when it kept them (RenderCache): the
  // same values the lines below would compute from the same inputs.
  const KeptCamera<S>* kept = nullptr;
  if (cache && cache->get<S>() && C == 1) {
    kept = cache->get<S>().get();
    TORCH_CHECK(kept->fits(N, D, W, H, near, far, camera_of(viewmats, Ks, 0)),
                "rasterizer backward: the kept forward state does not match these inputs");
  }
  Projected<S> own(kept ? 0 : N);
  const Projected<S>& P = kept ? kept->P : own;
  g_stats = Stats();
  const double tc = omp_get_wtime();
  // Groups in id order, without culling: the chain rule below runs over all splat ids and their
  // rects. (The backward serves the mapper, whose few cameras each see much of the map.)
  const SplatGroups<S> groups = kept ? SplatGroups<S>()
                                     : group_splats(means.data_ptr<S>(), U.data_ptr<S>(), V.data_ptr<S>(),
                                                    n.data_ptr<S>(), opac.data_ptr<S>(), N, false);
  g_stats.project += omp_get_wtime() - tc;
  Visible vis;
  Bins<S> fresh;
  for (int64_t c = 0; c < C; ++c) {
    const Camera cam = camera_of(viewmats, Ks, c);
    if (!kept) {
      const double t0 = omp_get_wtime();
      project_camera<S>(groups, cam, st, own, vis);
      g_stats.project += omp_get_wtime() - t0;
      const S* f = feats.data_ptr<S>() + (shared ? 0 : c * N * D);
      fresh = bin_and_sort(own, groups, vis, f, int(D), st, g_stats, keep_tiles ? keep_tiles + c * tiles : nullptr);
    }
    const Bins<S>& B = kept ? kept->B : fresh;
    if (kept) g_stats.isects += int64_t(B.ids.size());
    auto ptr = [&](const torch::Tensor& t, int64_t per) -> const S* {
      return t.numel() ? t.data_ptr<S>() + c * HW * per : nullptr;
    };
    BwdIn<S> in{ptr(fwd[0], D), ptr(fwd[1], 1), fl.normal ? ptr(fwd[2], 3) : nullptr,
                dz ? ptr(fwd[3], 1) : nullptr, dz ? ptr(fwd[4], 1) : nullptr, dz ? ptr(fwd[5], 1) : nullptr,
                fwd[6].data_ptr<int32_t>() + c * HW, fwd[7].data_ptr<int32_t>() + c * HW,
                ptr(grads[0], D), ptr(grads[1], 1), fl.normal ? ptr(grads[2], 3) : nullptr,
                dz ? ptr(grads[3], 1) : nullptr, dz ? ptr(grads[4], 1) : nullptr,
                dz ? ptr(grads[5], 1) : nullptr, ptr(grads[6], 1)};
    double t0 = omp_get_wtime();
    std::vector<S> slots(B.ids.size() * size_t(G), S(0));
#pragma omp parallel for schedule(dynamic, 1)
    for (int t = 0; t < tiles; ++t) {
      if (fisher) backward_tile<S, true>(t, B, int(D), st, fl, in, G, slots.data());
      else backward_tile<S, false>(t, B, int(D), st, fl, in, G, slots.data());
    }
    g_stats.blend += omp_get_wtime() - t0;
    t0 = omp_get_wtime();
    const std::vector<S> rows = reduce_slots(B, G, slots);
    g_stats.reduce += omp_get_wtime() - t0;
    t0 = omp_get_wtime();
    if (fisher) {
      fisher_rows(B, G, rows, fis_geo.data_ptr<S>() + c * N * NSYM, fis_o.data_ptr<S>() + c * N,
                  fis_w.data_ptr<S>() + c * N);
      g_stats.chain += omp_get_wtime() - t0;
      continue;
    }
    const SplatGrads<S> out{g_means.data_ptr<S>(), g_U.data_ptr<S>(), g_V.data_ptr<S>(), g_n.data_ptr<S>(),
                            g_op.data_ptr<S>(), g_feat.data_ptr<S>() + (shared ? 0 : c * N * D)};
    chain_to_splats(P, B, rows, G, N, D, cam, fl, out);
    g_stats.chain += omp_get_wtime() - t0;
  }
  if (fisher) return {fis_geo, fis_o, fis_w};
  return {g_means, g_U, g_V, g_n, g_op, g_feat};
}

}  // namespace

std::vector<torch::Tensor> backward(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                    torch::Tensor opac, torch::Tensor feats, torch::Tensor viewmats,
                                    torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                    bool normal, bool depth, bool dist,
                                    std::vector<torch::Tensor> fwd, std::vector<torch::Tensor> grads,
                                    bool fisher, torch::Tensor keep_tiles, RenderCache* cache) {
  const Flags fl{normal, depth, dist, true};
  const uint8_t* keep = tile_flags(keep_tiles, viewmats.size(0), W, H);
  if (means.scalar_type() == torch::kFloat64)
    return backward_impl<double>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, fwd, grads, fisher,
                                 keep, cache);
  return backward_impl<float>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, fwd, grads, fisher,
                              keep, cache);
}

}  // namespace raster

// The per-pixel arithmetic that the forward and the backward blend share: a tile's pixel slots, the
// pixel range a splat's box covers, and the ray-splat hit at a pixel row (Row, Hit: generic, any S,
// one pixel) followed by its AVX2 twin (RowVec, Hit8: float, 8 pixels). The forward and backward
// loops of each form evaluate the same alpha, so the backward retraces the forward's blend exactly.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "rasterize.h"

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#define FR_AVX2 1
#else
#define FR_AVX2 0
#endif

namespace raster {

// The image pixel of slot p of tile (tx, ty), and whether there is one: padding slots and slots past
// the image's right or bottom edge are never read out or blended.
struct SlotPixel {
  int x, y;
  bool in_image;
};
inline SlotPixel slot_pixel(int p, int tx, int ty, int W, int H) {
  const int c = p % RS, r = p / RS, x = tx * TS + c, y = ty * TS + r;
  return {x, y, c < TS && r < TS && x < W && y < H};
}

// A record's pixel range in tile (tx, ty): rows as pixel offsets [p0, p1) (stride RS), columns
// [c0, c1): whole groups from the box's first column, so a box up to LANES wide costs one group
// wherever it lies (aligned groups cost two for every box straddling column 8). Pixels past the
// box, padding included, get alpha < ALPHA_MIN (the box bounds it) or are inactive: they never blend.
// The AVX2 loops take a box at most 4 columns wide (most splats of a mapped scene: the low-pass
// filter's reach) as 4x2 groups, columns [c0, c0 + 4) of two rows, which halves its groups.
struct Span {
  int p0, p1, c0, c1;
  bool pairs;
};
inline Span span_of(const int* r, int tx, int ty) {
  const int c0 = std::max(r[0] - tx * TS, 0), cl = std::min(r[2] - tx * TS, TS - 1);
  return Span{std::max(r[1] - ty * TS, 0) * RS, (std::min(r[3] - ty * TS, TS - 1) + 1) * RS,
              c0, c0 + (cl - c0 + LANES) / LANES * LANES, cl - c0 < LANES / 2};
}

// The bit of a pixel group in Bins::blended: the AVX2 loops visit a record's groups in its span
// row by row, a 4x2 group (pairs) per two rows, else up to two 8-column groups per row (a box is at
// most TS wide), so a record has at most 32 groups in a tile.
inline int group_bit(const Span& sp, int p00, int c) {
  return sp.pairs ? (p00 - sp.p0) / (2 * RS) : 2 * ((p00 - sp.p0) / RS) + (c - sp.c0) / LANES;
}
static_assert(2 * TS <= 32 && TS <= 2 * LANES, "a record's groups in a tile fit Bins::blended's 32 bits");

// Per pixel row: l = y T_w - T_v is constant along a row, so q = k x l = x (T_w x l) - (T_u x l)
// is affine in x: three FMAs per pixel instead of a cross product.
template <typename S>
struct Row {
  S l0, l1, l2, a0, a1, a2, b0, b1, b2, dy2;
};

template <typename S>
inline Row<S> row_of(const S* M, S y, S my) {
  Row<S> r;
  r.l0 = y * M[6] - M[3];
  r.l1 = y * M[7] - M[4];
  r.l2 = y * M[8] - M[5];
  r.a0 = M[7] * r.l2 - M[8] * r.l1;
  r.a1 = M[8] * r.l0 - M[6] * r.l2;
  r.a2 = M[6] * r.l1 - M[7] * r.l0;
  r.b0 = M[1] * r.l2 - M[2] * r.l1;
  r.b1 = M[2] * r.l0 - M[0] * r.l2;
  r.b2 = M[0] * r.l1 - M[1] * r.l0;
  r.dy2 = (y - my) * (y - my);
  return r;
}

// Per-pixel geometry of one splat at one pixel: local (u, v), depth z, and alpha before the gates.
template <typename S>
struct Hit {
  S u, v, z, q2, rho3, rho2, g, a;
  bool use3, ok;
};

template <typename S>
inline Hit<S> hit(const S* M, const Row<S>& r, S mx, S o, S x, S near) {
  Hit<S> h;
  const S q0 = x * r.a0 - r.b0, q1 = x * r.a1 - r.b1, q2 = x * r.a2 - r.b2;
  const bool nz = q2 != 0;
  const S inv = S(1) / (nz ? q2 : S(1));
  h.q2 = q2;
  h.u = q0 * inv;
  h.v = q1 * inv;
  h.rho3 = std::min(h.u * h.u + h.v * h.v, S(1e4));
  const S dx = x - mx;
  h.rho2 = S(FILTER_INV_SQ) * (dx * dx + r.dy2);
  // Where the low-pass filter wins the hit is not on the splat: use the center depth (2DGS).
  h.use3 = h.rho3 <= h.rho2;
  h.z = h.use3 ? M[6] * h.u + M[7] * h.v + M[8] : M[8];
  h.g = std::exp(S(-0.5) * std::min(h.rho3, h.rho2));
  h.a = std::min(S(ALPHA_MAX), o * h.g);
  h.ok = nz && h.z >= near && h.a >= S(ALPHA_MIN);
  return h;
}

#if FR_AVX2
// The AVX2 twins of the above at 8 pixels: 8 columns of a row, or (PAIR) 4 columns of two rows.

// exp(x) for x <= 0 on 8 floats (Cephes' expf: Cody-Waite reduction and a degree-6 polynomial,
// about 2 ulp), inline so the blend does not call libmvec per vector. Below -87 it returns
// exp(-87) ~ 1.6e-38 instead of a denormal or 0: the alpha it gives is far under ALPHA_MIN either way.
inline __m256 exp_neg8(__m256 x) {
  x = _mm256_max_ps(x, _mm256_set1_ps(-87.0f));
  const __m256 fx = _mm256_round_ps(_mm256_mul_ps(x, _mm256_set1_ps(1.44269504088896341f)),
                                    _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
  x = _mm256_fnmadd_ps(fx, _mm256_set1_ps(0.693359375f), x);
  x = _mm256_fnmadd_ps(fx, _mm256_set1_ps(-2.12194440e-4f), x);
  __m256 y = _mm256_set1_ps(1.9875691500e-4f);
  y = _mm256_fmadd_ps(y, x, _mm256_set1_ps(1.3981999507e-3f));
  y = _mm256_fmadd_ps(y, x, _mm256_set1_ps(8.3334519073e-3f));
  y = _mm256_fmadd_ps(y, x, _mm256_set1_ps(4.1665795894e-2f));
  y = _mm256_fmadd_ps(y, x, _mm256_set1_ps(1.6666665459e-1f));
  y = _mm256_fmadd_ps(y, x, _mm256_set1_ps(5.0000001201e-1f));
  y = _mm256_fmadd_ps(y, _mm256_mul_ps(x, x), _mm256_add_ps(x, _mm256_set1_ps(1.0f)));
  const __m256i e = _mm256_slli_epi32(_mm256_add_epi32(_mm256_cvtps_epi32(fx), _mm256_set1_epi32(127)), 23);
  return _mm256_mul_ps(y, _mm256_castsi256_ps(e));
}

// A row's values of `hit` (Row) in 8 lanes.
struct RowVec {
  __m256 a0, a1, a2, b0, b1, b2, dy2;
};
inline RowVec row_vec(const Row<float>& rw) {
  return {_mm256_set1_ps(rw.a0), _mm256_set1_ps(rw.a1), _mm256_set1_ps(rw.a2), _mm256_set1_ps(rw.b0),
          _mm256_set1_ps(rw.b1), _mm256_set1_ps(rw.b2), _mm256_set1_ps(rw.dy2)};
}
// A 4x2 group's per-row values: a in lanes 0-3 (its first row), b in lanes 4-7.
inline __m256 halves(float a, float b) { return _mm256_set_m128(_mm_set1_ps(b), _mm_set1_ps(a)); }
inline RowVec row_vec(const Row<float>& a, const Row<float>& b) {
  return {halves(a.a0, b.a0), halves(a.a1, b.a1), halves(a.a2, b.a2), halves(a.b0, b.b0),
          halves(a.b1, b.b1), halves(a.b2, b.b2), halves(a.dy2, b.dy2)};
}
// The 8 pixels of a group from tile slot p: 8 columns of a row, or (PAIR) 4 columns of two rows.
template <bool PAIR>
inline __m256 load8(const float* p) {
  if constexpr (PAIR) return _mm256_loadu2_m128(p + RS, p);
  else return _mm256_loadu_ps(p);
}
template <bool PAIR>
inline void store8(float* p, __m256 v) {
  if constexpr (PAIR) _mm256_storeu2_m128(p + RS, p, v);
  else _mm256_storeu_ps(p, v);
}
template <bool PAIR>
inline __m256i load8i(const int32_t* p) {
  return _mm256_castps_si256(load8<PAIR>(reinterpret_cast<const float*>(p)));
}

// `hit` at 8 pixels of a row: ray-splat intersection (u, v) with its reciprocal, the screen-space
// low-pass fallback, depth and Gaussian weight (alpha and its gates are left to the loops).
struct Hit8 {
  __m256 nz, inv, u, v, dx, use3, z, g;
};
inline Hit8 hit8(__m256 x, const RowVec& r, __m256 vmx, __m256 m6, __m256 m7, __m256 m8) {
  const __m256 one = _mm256_set1_ps(1.0f);
  Hit8 h;
  const __m256 q0 = _mm256_fmsub_ps(x, r.a0, r.b0), q1 = _mm256_fmsub_ps(x, r.a1, r.b1);
  const __m256 q2 = _mm256_fmsub_ps(x, r.a2, r.b2);
  h.nz = _mm256_cmp_ps(q2, _mm256_setzero_ps(), _CMP_NEQ_UQ);
  h.inv = _mm256_div_ps(one, _mm256_blendv_ps(one, q2, h.nz));
  h.u = _mm256_mul_ps(q0, h.inv);
  h.v = _mm256_mul_ps(q1, h.inv);
  const __m256 rho3 = _mm256_min_ps(_mm256_fmadd_ps(h.u, h.u, _mm256_mul_ps(h.v, h.v)), _mm256_set1_ps(1e4f));
  h.dx = _mm256_sub_ps(x, vmx);
  const __m256 rho2 = _mm256_mul_ps(_mm256_set1_ps(float(FILTER_INV_SQ)), _mm256_fmadd_ps(h.dx, h.dx, r.dy2));
  h.use3 = _mm256_cmp_ps(rho3, rho2, _CMP_LE_OQ);
  h.z = _mm256_blendv_ps(m8, _mm256_fmadd_ps(m6, h.u, _mm256_fmadd_ps(m7, h.v, m8)), h.use3);
  h.g = exp_neg8(_mm256_mul_ps(_mm256_set1_ps(-0.5f), _mm256_min_ps(rho3, rho2)));
  return h;
}
#endif

}  // namespace raster

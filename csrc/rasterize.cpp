// 2DGS CPU rasterizer: projection, tile binning, per-tile depth sort, front-to-back blending with
// early termination, and the analytic backward pass (optionally the FisherRF squared mode).
//
// The equations are those of flightrecon/render/projection.py (the readable statement, tested
// against gsplat) and of the 2DGS section of spec/baselines.md. Once per call, the splats are
// grouped spatially for culling (SplatGroups). Per camera: project the splats of the groups that
// may reach the frustum (parallel over groups), sort the binned ones by depth (ties keep the lower
// index), list them per 16x16 tile in that order, then blend each tile (parallel over tiles), or
// a whole camera per thread when there are many cameras. The blend loops run
// splats outside and the tile's pixels inside, branch-free, so the compiler vectorizes them over
// pixels; only the pixel groups that a splat's box covers are visited (span_of). A single camera's
// forward can keep its projection and bins for the backward (RenderCache), which otherwise
// recomputes them.
//
// Determinism: every float sum has a fixed order independent of the thread count. The backward
// writes each (tile, splat) pair's gradient into its own slot and reduces the slots per splat in
// tile order; cameras are reduced in camera order.

#include <torch/extension.h>

#include "bindings.h"
#include <omp.h>
#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#define FR_AVX2 1
#else
#define FR_AVX2 0
#endif

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <map>
#include <memory>
#include <numeric>
#include <string>
#include <vector>

namespace {

constexpr int TS = 16;          // tile side
constexpr int LANES = 8;        // pixel group: one AVX2 float vector; a splat's groups start at its box's first column
constexpr int RS = TS + LANES;  // row stride of a tile's pixel arrays: a group from any column stays in its row
constexpr int TP = (TS + 1) * RS;  // pixel slots per tile: padding columns and a padding row, never blended
constexpr double ALPHA_MIN = 1.0 / 255.0;
constexpr double ALPHA_MAX = 0.99;
constexpr double T_MIN = 1e-4;
constexpr double CUTOFF = 3.33;
constexpr double FILTER_INV_SQ = 2.0;
constexpr double FILTER_REACH = 2.36;
constexpr double BOX_EPS = 1e-3;
constexpr double RHO_MARGIN = 1e-3;  // alpha margin exp(-5e-4): covers float error of rho and exp
constexpr int NG = 11;           // per-pixel geometric gradient: T_u, T_v, T_w (9), means2d (2)
constexpr int NSYM = NG * (NG + 1) / 2;

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

// One camera's projected splats (struct of arrays over all N splats, by SplatGroups position).
// Only the splats of the groups that pass the camera's frustum test are written (project_camera);
// the backward, which reads every splat's rect, does not cull.
template <typename S>
struct Projected {
  std::vector<S> M, m2d, depth, nrm, sign;
  std::vector<int> rect;  // px0, py0, px1, py1 (inclusive); px0 > px1 when not binned
  std::vector<int> radii;
  explicit Projected(int64_t n)
      : M(9 * n), m2d(2 * n), depth(n), nrm(3 * n), sign(n), rect(4 * n), radii(n) {}
};

#if FR_AVX2
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
#endif

// One camera's binned splats. The splats that touch the image are packed into contiguous records
// (the blend reads one record per splat instead of chasing ids through N-sized arrays), sorted
// once by depth, and each tile lists its records in that order, so no per-tile sort is needed.
constexpr int REC = 15;  // record: ray transform (9), means2d (2), opacity, normal (3); features follow
template <typename S>
struct Bins {
  std::vector<int64_t> offsets;  // [tiles + 1]
  std::vector<int32_t> ids;      // per tile: record indices in depth order
  std::vector<int32_t> splat;    // record -> splat id
  std::vector<int32_t> rect;     // record -> px0, py0, px1, py1 (inclusive)
  std::vector<S> rec;            // records, REC + D values each
  int R = REC;
  std::vector<int64_t> ends;     // per tile, where its blend stops when shorter than its list (feature_sums)
};

// Phase timings (seconds) and blend work of the last forward or backward call, for profiling.
struct Stats {
  double project = 0, bin = 0, sort = 0, blend = 0, reduce = 0, chain = 0;
  int64_t evals = 0, blends = 0, isects = 0;  // pixel-splat evaluations, those that blend, tile-splat pairs
  bool by_camera = false;  // timings are then summed over threads (thread-seconds), not wall time
  void add(const Stats& o) {
    project += o.project; bin += o.bin; sort += o.sort; blend += o.blend; reduce += o.reduce;
    chain += o.chain; evals += o.evals; blends += o.blends; isects += o.isects;
  }
};
Stats g_stats;

struct Camera {
  double R[9], t[3], K[9];
};

struct Settings {
  int W, H, tiles_x, tiles_y;
  double near, far;
};

template <typename S>
void conic_box(const S* Tu, const S* Tv, const S* Tw, S cs, S& cx, S& cy, S& ex, S& ey, S& d) {
  // Image of the circle u^2 + v^2 = cs^2 under (u, v, 1) -> M (u, v, 1): center and half extents.
  const S tw0 = cs * Tw[0], tw1 = cs * Tw[1], tw2 = Tw[2];
  d = tw0 * tw0 + tw1 * tw1 - tw2 * tw2;
  if (d == 0) d = S(-1e-30);
  const S tu0 = cs * Tu[0], tu1 = cs * Tu[1], tv0 = cs * Tv[0], tv1 = cs * Tv[1];
  cx = (tu0 * tw0 + tu1 * tw1 - Tu[2] * tw2) / d;
  cy = (tv0 * tw0 + tv1 * tw1 - Tv[2] * tw2) / d;
  const S sx = (tu0 * tu0 + tu1 * tu1 - Tu[2] * Tu[2]) / d;
  const S sy = (tv0 * tv0 + tv1 * tv1 - Tv[2] * Tv[2]) / d;
  ex = std::sqrt(std::max(cx * cx - sx, S(1e-4)));
  ey = std::sqrt(std::max(cy * cy - sy, S(1e-4)));
}

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

// Splats regrouped for frustum culling, once per call (nothing here depends on the camera): sorted
// along a Morton curve of their means, so each run of GROUP consecutive positions is spatially
// compact, and each run (group) gets a sphere holding its splats' bounding spheres. A camera then
// projects only the splats of the groups whose sphere may reach its frustum, instead of all N.
// Without culling (one camera) the splats stay in id order and nothing is copied.
// The per-splat values that do not depend on the camera live here too, in the same order: the
// bounding-sphere radius of the frustum test and the opacity-aware cutoff (rho_max, <= 0 when the
// splat can never reach ALPHA_MIN) with its conic scale and filter reach.
constexpr int GROUP = 32;  // splats per culling group
constexpr int MORTON_BITS = 10;  // per axis

template <typename S>
struct SplatGroups {
  int64_t N = 0;
  std::vector<int32_t> id;                   // position -> splat id
  const S *mean, *U, *V, *n, *opac;          // by position (3 values a splat, opac 1)
  std::vector<S> sorted;                     // what they point to when culling, else the inputs
  std::vector<S> rad, cut, freach;
  std::vector<double> rho_max;
  std::vector<double> sphere;                // per group when culling: center (3), radius
  SplatGroups() = default;
  SplatGroups(const SplatGroups&) = delete;  // the pointers may point into `sorted`
  SplatGroups(SplatGroups&&) = default;
  bool culls() const { return !sphere.empty(); }
  int groups() const { return int((N + GROUP - 1) / GROUP); }
  int64_t begin(int g) const { return int64_t(g) * GROUP; }
  int64_t end(int g) const { return std::min(N, int64_t(g + 1) * GROUP); }
};

// The low MORTON_BITS bits of v spread to every third bit.
inline uint32_t spread_bits(uint32_t v) {
  v &= 0x3ffu;
  v = (v | (v << 16)) & 0x030000ffu;
  v = (v | (v << 8)) & 0x0300f00fu;
  v = (v | (v << 4)) & 0x030c30c3u;
  v = (v | (v << 2)) & 0x09249249u;
  return v;
}

// Splat ids in Morton order of their means quantized in the means' bounding box.
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

// Copies splat g.id[s] to position s of `sorted`.
template <typename S>
void gather_splat(SplatGroups<S>& g, int64_t s, const S* means, const S* U, const S* V, const S* n, const S* opac) {
  const int64_t i = g.id[s], N = g.N;
  S* out = g.sorted.data();
  for (int a = 0; a < 3; ++a) {
    out[3 * s + a] = means[3 * i + a];
    out[3 * (N + s) + a] = U[3 * i + a];
    out[3 * (2 * N + s) + a] = V[3 * i + a];
    out[3 * (3 * N + s) + a] = n[3 * i + a];
  }
  out[12 * N + s] = opac[i];
}

// Radius of a splat's bounding sphere around its mean: holds the cutoff ellipse (and the center).
template <typename S>
inline S sphere_radius(const S* u, const S* v) {
  return S(CUTOFF * 1.01) * std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2] + v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

// The camera-independent values of the splat at position s.
template <typename S>
void splat_consts(SplatGroups<S>& g, int64_t s) {
  const S* u = g.U + 3 * s;
  const S* v = g.V + 3 * s;
  g.rad[s] = sphere_radius(u, v);
  // alpha = o exp(-rho / 2) reaches ALPHA_MIN only where rho <= 2 ln(o / ALPHA_MIN) (plus a
  // margin for float error); never more than the fixed CUTOFF, which is the o = 1 case
  const double rho_max = std::min(2.0 * std::log(double(g.opac[s]) / ALPHA_MIN) + RHO_MARGIN, CUTOFF * CUTOFF);
  g.rho_max[s] = rho_max;
  g.cut[s] = rho_max > 0 ? S(std::sqrt(rho_max)) : S(0);
  g.freach[s] = rho_max > 0 ? S(std::min(FILTER_REACH, std::sqrt(rho_max / FILTER_INV_SQ))) : S(0);
}

// Group k's sphere: its means' box center, and a radius that holds each splat's bounding sphere.
template <typename S>
void bound_group(SplatGroups<S>& g, int k) {
  const int64_t s0 = g.begin(k), s1 = g.end(k);
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = g.mean[3 * s0 + a];
  for (int64_t s = s0 + 1; s < s1; ++s)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], double(g.mean[3 * s + a]));
      hi[a] = std::max(hi[a], double(g.mean[3 * s + a]));
    }
  double* c = &g.sphere[4 * size_t(k)];
  for (int a = 0; a < 3; ++a) c[a] = 0.5 * (lo[a] + hi[a]);
  double r = 0;
  for (int64_t s = s0; s < s1; ++s) {
    const S* p = &g.mean[3 * s];
    const double dx = p[0] - c[0], dy = p[1] - c[1], dz = p[2] - c[2];
    r = std::max(r, std::sqrt(dx * dx + dy * dy + dz * dz) + double(g.rad[s]));
  }
  c[3] = r;
}

// spatial: groups in Morton order, for culling; else in id order (position == id), no culling.
template <typename S>
SplatGroups<S> group_splats(const S* means, const S* U, const S* V, const S* n, const S* opac, int64_t N,
                            bool spatial) {
  SplatGroups<S> g;
  g.N = N;
  if (spatial) {
    g.id = morton_order(means, N);
    g.sorted.resize(13 * size_t(N));
    S* m = g.sorted.data();
    g.mean = m, g.U = m + 3 * N, g.V = m + 6 * N, g.n = m + 9 * N, g.opac = m + 12 * N;
    g.sphere.resize(4 * size_t(g.groups()));
  } else {
    g.id.resize(N);
    std::iota(g.id.begin(), g.id.end(), 0);
    g.mean = means, g.U = U, g.V = V, g.n = n, g.opac = opac;
  }
  g.rad.resize(N); g.cut.resize(N); g.freach.resize(N); g.rho_max.resize(N);
  const int G = g.groups();
#pragma omp parallel for schedule(static)
  for (int k = 0; k < G; ++k) {
    for (int64_t s = g.begin(k); s < g.end(k); ++s) {
      if (spatial) gather_splat(g, s, means, U, V, n, opac);
      splat_consts(g, s);
    }
    if (spatial) bound_group(g, k);
  }
  return g;
}

// Frustum planes through the camera center, widened by the low-pass filter's reach in pixels
// (plus a margin): a splat whose bounding sphere (radius CUTOFF |(U, V)|, which holds the cutoff
// ellipse and the projected center) lies wholly outside one of them cannot touch the image, so
// it is rejected before the costly part of the projection. Only for plain pinhole K.
struct Frustum {
  bool pinhole;
  double planes[4][2];  // (a, b): a * x_or_y + b * z >= 0 inside; index 0, 1 act on x, 2, 3 on y
};

inline Frustum frustum_of(const Camera& cam, const Settings& st) {
  const double* K = cam.K;
  Frustum fr;
  fr.pinhole = K[1] == 0 && K[3] == 0 && K[6] == 0 && K[7] == 0 && K[8] == 1 && K[0] > 0 && K[4] > 0;
  const double m = FILTER_REACH + 1.0;
  const double ab[4][2] = {{K[0], K[2] + m}, {-K[0], st.W + m - K[2]}, {K[4], K[5] + m}, {-K[4], st.H + m - K[5]}};
  for (int k = 0; k < 4; ++k) {
    const double len = std::sqrt(ab[k][0] * ab[k][0] + ab[k][1] * ab[k][1]);
    fr.planes[k][0] = ab[k][0] / len;
    fr.planes[k][1] = ab[k][1] / len;
  }
  return fr;
}

// Whether every splat of a group fails the per-splat frustum test of project_splat: the group's
// sphere lies outside a plane (or behind the near plane) by more than a margin that covers the
// float rounding of that test, so culling a group never drops a splat the test would keep.
inline bool group_outside(const double* sph, const Camera& cam, const Frustum& fr, double near) {
  double c[3];
  for (int r = 0; r < 3; ++r)
    c[r] = cam.R[3 * r] * sph[0] + cam.R[3 * r + 1] * sph[1] + cam.R[3 * r + 2] * sph[2] + cam.t[r];
  const double scale = 1.0 + std::fabs(c[0]) + std::fabs(c[1]) + std::fabs(c[2]) + sph[3] +
                       std::fabs(cam.t[0]) + std::fabs(cam.t[1]) + std::fabs(cam.t[2]);
  const double r = sph[3] + 1e-4 * scale;
  if (c[2] + r <= near) return true;
  for (int k = 0; k < 4; ++k)
    if (fr.planes[k][0] * c[k / 2] + fr.planes[k][1] * c[2] < -r) return true;
  return false;
}

template <typename S>
inline void camera_point(const Camera& cam, const S* p, S* pc) {
  for (int r = 0; r < 3; ++r) {
    const double* Rr = cam.R + 3 * r;
    pc[r] = S(Rr[0]) * p[0] + S(Rr[1]) * p[1] + S(Rr[2]) * p[2] + S(cam.t[r]);
  }
}

// The first test of project_splat: the mean (camera frame pc) is not beyond the near plane, or the
// bounding sphere lies wholly outside a widened frustum plane (pinhole K only); both by more than
// `slack`, which candidate_rows sets to cover the float rounding of the test (the compiler may fuse
// its multiply-adds differently there), so that it never drops a splat project_splat keeps.
template <typename S>
inline bool sphere_outside(const S* pc, S rad, const Frustum& fr, const Settings& st, S slack = S(0)) {
  if (!fr.pinhole) return false;
  bool out = !(pc[2] > S(st.near) - slack);
  for (int k = 0; k < 4; ++k)
    out = out || S(fr.planes[k][0]) * pc[k / 2] + S(fr.planes[k][1]) * pc[2] < -(rad + slack);
  return out;
}

// Projects the splat at position s into P (same position); whether it touches the image (is
// binned; else its rect stays empty, px0 > px1).
template <typename S>
bool project_splat(const SplatGroups<S>& G, int64_t s, const Camera& cam, const Frustum& fr,
                   const Settings& st, Projected<S>& P) {
  S pc[3], uc[3], vc[3], nc[3];
  camera_point(cam, &G.mean[3 * s], pc);
  int* rect = &P.rect[4 * s];
  rect[0] = 1; rect[2] = 0;
  P.radii[s] = 0;
  if (sphere_outside(pc, G.rad[s], fr, st)) return false;
  const S *U = &G.U[3 * s], *V = &G.V[3 * s], *n = &G.n[3 * s];
  for (int r = 0; r < 3; ++r) {
    const double* Rr = cam.R + 3 * r;
    uc[r] = S(Rr[0]) * U[0] + S(Rr[1]) * U[1] + S(Rr[2]) * U[2];
    vc[r] = S(Rr[0]) * V[0] + S(Rr[1]) * V[1] + S(Rr[2]) * V[2];
    nc[r] = S(Rr[0]) * n[0] + S(Rr[1]) * n[1] + S(Rr[2]) * n[2];
  }
  const S sgn = (nc[0] * pc[0] + nc[1] * pc[1] + nc[2] * pc[2]) < 0 ? S(1) : S(-1);
  P.sign[s] = sgn;
  for (int r = 0; r < 3; ++r) P.nrm[3 * s + r] = sgn * nc[r];
  S* M = &P.M[9 * s];
  for (int r = 0; r < 3; ++r) {
    const double* Kr = cam.K + 3 * r;
    M[3 * r + 0] = S(Kr[0]) * uc[0] + S(Kr[1]) * uc[1] + S(Kr[2]) * uc[2];
    M[3 * r + 1] = S(Kr[0]) * vc[0] + S(Kr[1]) * vc[1] + S(Kr[2]) * vc[2];
    M[3 * r + 2] = S(Kr[0]) * pc[0] + S(Kr[1]) * pc[1] + S(Kr[2]) * pc[2];
  }
  const S z = pc[2];
  P.depth[s] = z;
  const S reach = S(CUTOFF) * std::sqrt(uc[2] * uc[2] + vc[2] * vc[2]);
  if (!(z > S(st.near) && z < S(st.far) && z - reach > 0)) return false;
  S cx, cy, ex, ey, d;
  conic_box(M, M + 3, M + 6, S(1), cx, cy, ex, ey, d);
  P.m2d[2 * s] = cx;
  P.m2d[2 * s + 1] = cy;
  S bx, by, bex, bey, bd;
  conic_box(M, M + 3, M + 6, S(CUTOFF), bx, by, bex, bey, bd);
  S lox = std::min(bx - bex, cx - S(FILTER_REACH)), hix = std::max(bx + bex, cx + S(FILTER_REACH));
  S loy = std::min(by - bey, cy - S(FILTER_REACH)), hiy = std::max(by + bey, cy + S(FILTER_REACH));
  if (!(hix > 0 && lox < S(st.W) && hiy > 0 && loy < S(st.H))) return false;
  P.radii[s] = int(std::ceil(S(CUTOFF) * std::max(ex, ey)));  // geometric: independent of opacity
  // Opacity-aware extent (SplatGroups): the binned box (and with it the tiles and the blend's rows
  // and column groups) shrinks with the opacity; never wider than the fixed CUTOFF / FILTER_REACH
  // box above, which is the o = 1 case.
  if (!(G.rho_max[s] > 0)) return false;
  const S cut = G.cut[s], freach = G.freach[s];
  conic_box(M, M + 3, M + 6, cut, bx, by, bex, bey, bd);
  lox = std::min(bx - bex, cx - freach), hix = std::max(bx + bex, cx + freach);
  loy = std::min(by - bey, cy - freach), hiy = std::max(by + bey, cy + freach);
  if (!(hix > 0 && lox < S(st.W) && hiy > 0 && loy < S(st.H))) return false;
  // Pixel i is covered when lo <= i + 0.5 <= hi; clamp in double before converting to int.
  rect[0] = int(std::max(0.0, std::ceil(double(lox) - 0.5 - BOX_EPS)));
  rect[1] = int(std::max(0.0, std::ceil(double(loy) - 0.5 - BOX_EPS)));
  rect[2] = int(std::min(double(st.W - 1), std::floor(double(hix) - 0.5 + BOX_EPS)));
  rect[3] = int(std::min(double(st.H - 1), std::floor(double(hiy) - 0.5 + BOX_EPS)));
  return rect[0] <= rect[2] && rect[1] <= rect[3];  // the box may fall between pixel centers
}

// What one camera may see: the groups that pass the frustum test (their splats are projected, the
// others keep radius 0) and, of their splats, the positions that touch the image, increasing.
struct Visible {
  std::vector<int32_t> groups;
  std::vector<uint32_t> masks;  // per passing group: a bit for each binned splat
  std::vector<int32_t> binned;
};
static_assert(GROUP <= 32, "a group's binned splats are one 32-bit mask");

template <typename S>
void project_camera(const SplatGroups<S>& G, const Camera& cam, const Settings& st, Projected<S>& P,
                    Visible& vis) {
  const Frustum fr = frustum_of(cam, st);
  vis.groups.clear();
  for (int k = 0; k < G.groups(); ++k)
    if (!(fr.pinhole && G.culls() && group_outside(&G.sphere[4 * size_t(k)], cam, fr, st.near))) vis.groups.push_back(k);
  const int ng = int(vis.groups.size());
  vis.masks.resize(ng);
#pragma omp parallel for schedule(static)
  for (int e = 0; e < ng; ++e) {
    const int64_t s0 = G.begin(vis.groups[e]), s1 = G.end(vis.groups[e]);
    uint32_t mask = 0;
    for (int64_t s = s0; s < s1; ++s) mask |= uint32_t(project_splat(G, s, cam, fr, st, P)) << (s - s0);
    vis.masks[e] = mask;
  }
  // the binned positions from the masks (not from P's rects, which are out of cache by now)
  vis.binned.clear();
  for (int e = 0; e < ng; ++e)
    for (uint32_t m = vis.masks[e]; m != 0; m &= m - 1)
      vis.binned.push_back(int32_t(G.begin(vis.groups[e]) + __builtin_ctz(m)));
}

// One camera's radii by splat id (0 where not visible).
template <typename S>
void write_radii(const SplatGroups<S>& G, const Visible& vis, const Projected<S>& P, int32_t* radii) {
  if (int(vis.groups.size()) < G.groups()) std::fill(radii, radii + G.N, 0);  // some were culled
  for (const int k : vis.groups)
    for (int64_t s = G.begin(k); s < G.end(k); ++s) radii[G.id[s]] = P.radii[s];
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

template <typename S>
Bins<S> bin_and_sort(const Projected<S>& P, const SplatGroups<S>& G, const Visible& vis, const S* feat, int D,
                     const Settings& st, Stats& stats) {
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
  for (int64_t k = 0; k < V; ++k) {
    const int* r = &b.rect[4 * k];
    for (int ty = r[1] / TS; ty <= r[3] / TS; ++ty)
      for (int tx = r[0] / TS; tx <= r[2] / TS; ++tx) ++b.offsets[ty * st.tiles_x + tx + 1];
  }
  for (int t = 0; t < tiles; ++t) b.offsets[t + 1] += b.offsets[t];
  b.ids.resize(b.offsets[tiles]);
  std::vector<int64_t> fill(b.offsets.begin(), b.offsets.end() - 1);
  for (int64_t k : order) {
    const int* r = &b.rect[4 * k];
    for (int ty = r[1] / TS; ty <= r[3] / TS; ++ty)
      for (int tx = r[0] / TS; tx <= r[2] / TS; ++tx) b.ids[fill[ty * st.tiles_x + tx]++] = int32_t(k);
  }
  stats.bin += (t1 - t0) + (omp_get_wtime() - t2);
  stats.sort += t2 - t1;
  stats.isects += int64_t(b.ids.size());
  return b;
}

// Per-pixel geometry of one splat at one pixel: local (u, v), depth z, and alpha before the gates.
template <typename S>
struct Hit {
  S u, v, z, q2, rho3, rho2, g, a;
  bool use3, ok;
};

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

#if FR_AVX2
// The AVX2 form of `hit` at 8 pixels of a row: ray-splat intersection (u, v) with its reciprocal,
// the screen-space low-pass fallback, depth and Gaussian weight. Shared by the forward and backward
// loops so both evaluate the same alpha.
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

struct Flags {
  bool normal, depth, dist;
  bool track;  // median depth and the last/median splat per pixel (the backward needs them)
};

template <typename S>
struct FwdOut {
  S *feat, *alpha, *normal, *zsum, *msum, *m2sum, *median;
  int32_t *last, *medj;
};

struct TileWork {
  int64_t evals = 0, blends = 0;
};

template <typename S, bool TRACK>
TileWork forward_tile(int tile, const Bins<S>& B, int D, const Settings& st, const Flags& fl,
                     const FwdOut<S>& out) {
  const int tx = tile % st.tiles_x, ty = tile / st.tiles_x;
  alignas(64) S px[TP], py[TP], T[TP], act[TP], w[TP], zz[TP];
  alignas(64) S accA[TP], accZ[TP], accM[TP], accM2[TP], medz[TP];
  alignas(64) int32_t last[TP], medj[TP];
  bool row_alive[TS];
  for (int r = 0; r < TS; ++r) row_alive[r] = ty * TS + r < st.H;
  std::vector<S> accF(size_t(D) * TP, S(0)), accN(fl.normal ? 3 * TP : 0, S(0));
  for (int p = 0; p < TP; ++p) {
    const SlotPixel sl = slot_pixel(p, tx, ty, st.W, st.H);
    px[p] = S(sl.x) + S(0.5);
    py[p] = S(sl.y) + S(0.5);
    act[p] = sl.in_image ? S(1) : S(0);
    T[p] = S(1);
    accA[p] = accZ[p] = accM[p] = accM2[p] = medz[p] = w[p] = S(0);
    zz[p] = S(st.near);
    last[p] = 0;
    medj[p] = -1;
  }
  const S near = S(st.near), mscale = S(st.far / (st.far - st.near));
  const int64_t b0 = B.offsets[tile], b1 = B.ends.empty() ? B.offsets[tile + 1] : B.ends[tile];
  int64_t evals = 0, blends = 0;
#if FR_AVX2
  if constexpr (std::is_same<S, float>::value) {
    // The same per-pixel arithmetic as the generic loop below, in AVX2 registers: one group of 8
    // pixels at a time (8 columns of a row, or 4 of two rows for a narrow box), its weights going
    // straight into the accumulators (only the groups a splat covers are visited), the blend masks
    // kept in registers instead of masked stores, and exp inline. Records are prefetched a few
    // splats ahead (the tile lists them in depth order, scattered in memory).
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
      // One group at slot pg (see load8); returns the mask of its pixels that terminate.
      auto group = [&](auto pair, int pg, const RowVec& rv) -> int {
        constexpr bool P = decltype(pair)::value;
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
        if (!bm) return sm;
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
        return sm;
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
          const uint32_t sm = uint32_t(group(std::true_type{}, p00 + sp.c0, rv));
          terminate(r, sm & 0xfu, sp.c0);
          terminate(r + 1, sm >> 4, sp.c0);
        }
        continue;
      }
      for (int p00 = sp.p0; p00 < sp.p1; p00 += RS) {
        const int r = p00 / RS;
        if (live[r] == 0) continue;  // every pixel of this row has terminated
        const RowVec rv = row_vec(row_of(M, py[p00], my));
        for (int c = sp.c0; c < sp.c1; c += LANES) {
          if (((live[r] >> c) & 0xffu) == 0) continue;  // its 8 pixels have terminated
          terminate(r, uint32_t(group(std::false_type{}, p00 + c, rv)), c);
        }
      }
    }
  } else
#endif
  {
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
  }
  for (int p = 0; p < TP; ++p) {
    const SlotPixel sl = slot_pixel(p, tx, ty, st.W, st.H);
    if (!sl.in_image) continue;
    const int64_t q = int64_t(sl.y) * st.W + sl.x;
    for (int d = 0; d < D; ++d) out.feat[q * D + d] = accF[size_t(d) * TP + p];
    out.alpha[q] = accA[p];
    if (fl.normal)
      for (int k = 0; k < 3; ++k) out.normal[q * 3 + k] = accN[size_t(k) * TP + p];
    if (fl.depth || fl.dist) { out.zsum[q] = accZ[p]; out.msum[q] = accM[p]; out.m2sum[q] = accM2[p]; }
    if constexpr (TRACK) {
      out.median[q] = medz[p];
      out.last[q] = last[p];
      out.medj[q] = medj[p];
    }
  }
  return TileWork{evals, blends};
}

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

Settings settings_of(int64_t W, int64_t H, double near, double far) {
  return Settings{int(W), int(H), int((W + TS - 1) / TS), int((H + TS - 1) / TS), near, far};
}

// One camera's projection and bins as a forward call computed them, kept for its backward (which
// would otherwise redo the same projection, binning and sort). Only a single camera's are kept:
// its splats stay in id order, the order the backward works in; a batch's forward orders them
// spatially. Python holds it as an opaque handle; the backward checks that it fits its inputs.
template <typename S>
struct KeptCamera {
  Projected<S> P;
  Bins<S> B;
  int64_t N, D, W, H;
  double near, far;
  Camera cam;
  bool fits(int64_t n, int64_t d, int64_t w, int64_t h, double nr, double fr, const Camera& c) const {
    return n == N && d == D && w == W && h == H && nr == near && fr == far &&
           std::memcmp(&c, &cam, sizeof(Camera)) == 0;
  }
};

struct RenderCache {
  std::unique_ptr<KeptCamera<float>> f;
  std::unique_ptr<KeptCamera<double>> d;
  template <typename S>
  std::unique_ptr<KeptCamera<S>>& get() {
    if constexpr (std::is_same<S, float>::value) return f;
    else return d;
  }
};

template <typename S>
std::vector<torch::Tensor> forward_impl(torch::Tensor means, torch::Tensor U, torch::Tensor V,
                                        torch::Tensor n, torch::Tensor opac, torch::Tensor feats,
                                        torch::Tensor viewmats, torch::Tensor Ks, int64_t W, int64_t H,
                                        double near, double far, const Flags& fl, RenderCache* cache) {
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
    Bins<S> B = bin_and_sort(P, groups, vis, f, int(D), st, sc);
    const int64_t HW = H * W;
    FwdOut<S> out{feat_img.data_ptr<S>() + c * HW * D, alpha.data_ptr<S>() + c * HW,
                  fl.normal ? normal.data_ptr<S>() + c * HW * 3 : nullptr,
                  dz ? zsum.data_ptr<S>() + c * HW : nullptr, dz ? msum.data_ptr<S>() + c * HW : nullptr,
                  dz ? m2sum.data_ptr<S>() + c * HW : nullptr, fl.track ? median.data_ptr<S>() + c * HW : nullptr,
                  fl.track ? last.data_ptr<int32_t>() + c * HW : nullptr,
                  fl.track ? medj.data_ptr<int32_t>() + c * HW : nullptr};
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

// ---------------------------------------------------------------- sided feature sums
// Per camera, the sum over pixels of a rendered one-channel feature that each splat takes from the
// side the camera sees: value[0] where w = n . (c - mu) / |c - mu| > w_min, value[1] where
// w < -w_min, 0 otherwise, times |w| when `weighted` (the information gain of 2D GauSS-MI, docs/).
// With floor > 0, each tile stops blending after its last splat whose feature reaches the floor:
// the splats it drops all carry less than floor, and the weight left behind the cut at a pixel is
// its transmittance there, so the exact sum lies in [sum, sum + bound] with
// bound = floor * sum over the cut tiles' pixels of (1 - blended alpha) (float rounding aside).
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
      Bins<S> B = bin_and_sort(P, groups, vis, feat.data(), 1, st, sc);
      std::vector<char> cut(tiles, 0);
      if (floor > 0) {
        B.ends.resize(tiles);
        for (int t = 0; t < tiles; ++t) {
          int64_t e = B.offsets[t + 1];
          while (e > B.offsets[t] && !(B.rec[size_t(B.ids[e - 1]) * B.R + REC] >= S(floor))) --e;
          B.ends[t] = e;
          cut[t] = e < B.offsets[t + 1];
        }
      }
      t0 = omp_get_wtime();
      const FwdOut<S> out{img.data(), alpha.data(), nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr};
      for (int t = 0; t < tiles; ++t) {
        const TileWork tw = forward_tile<S, false>(t, B, 1, st, fl, out);
        sc.evals += tw.evals;
        sc.blends += tw.blends;
      }
      sc.blend += omp_get_wtime() - t0;
      double total = 0, left = 0;
      for (int64_t y = 0; y < H; ++y)
        for (int64_t x = 0; x < W; ++x) {
          total += double(img[y * W + x]);
          if (cut[(y / TS) * st.tiles_x + x / TS]) left += std::max(0.0, 1.0 - double(alpha[y * W + x]));
        }
      out_sum[c] = total;
      out_bound[c] = floor * left;
      for (const int32_t s : vis.binned) feat[groups.id[s]] = S(0);
    }
  }
  g_stats = Stats();
  g_stats.by_camera = true;
  for (const Stats& sc : per) g_stats.add(sc);
  g_stats.project += groups_s;
  return {sums, bound};
}

// ---------------------------------------------------------------- backward

template <typename S>
struct BwdIn {
  const S *feat, *alpha, *normal, *zsum, *msum, *m2sum;          // forward outputs
  const int32_t *last, *medj;
  const S *gF, *gA, *gN, *gZ, *gM, *gM2, *gMed;                   // upstream gradients
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

// The backward blend of one tile for float (not the Fisher mode): the per-pixel arithmetic of the
// generic loop in backward_tile, in AVX2 registers, with each splat's per-pixel gradient terms summed
// in 8-lane registers over the groups it covers (one horizontal sum per slot entry at the end)
// instead of being stored per pixel and reduced over whole box rows.
void backward_splats_avx2(const Bins<float>& B, int D, const Flags& fl, int tx, int ty, int64_t b0, int maxlast,
                          const int32_t* row_last, const float* px, const float* py, float* T, float* Pre,
                          const float* Tot, const float* gA, const float* gZ, const float* gM, const float* gM2,
                          const float* gMed, const int32_t* last, const int32_t* medj, const float* gF,
                          const float* gN, int G, float* slots, const Settings& st) {
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
        group(std::true_type{}, p00 + sp.c0, row_b(M, py[p00], py[p00 + RS], my));
      }
    } else {
      for (int p00 = sp.p0; p00 < sp.p1; p00 += RS) {
        if (j >= row_last[p00 / RS]) continue;  // no pixel of this row blends this splat or any later one
        const RowB rb = row_b(M, py[p00], my);
        for (int pg = p00 + sp.c0; pg < p00 + sp.c1; pg += LANES) group(std::false_type{}, pg, rb);
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

// Slot layout per (tile, splat): geometric 11 (T_u, T_v, T_w, means2d), opacity, normal 3, feat D.
// In Fisher mode: NSYM outer-product entries, sum of dL/do^2, sum of w^2.
template <typename S, bool FISHER>
void backward_tile(int tile, const Bins<S>& B, int D, const Settings& st, const Flags& fl,
                   const BwdIn<S>& in, int G, S* slots) {
  const int tx = tile % st.tiles_x, ty = tile / st.tiles_x;
  alignas(64) S px[TP], py[TP], T[TP], Pre[TP], Tot[TP], s[TP], w[TP];
  alignas(64) S gA[TP], gZ[TP], gM[TP], gM2[TP], gMed[TP];
  alignas(64) int32_t last[TP], medj[TP];
  alignas(64) S gg[NG][TP];
  std::vector<S> gF(size_t(D) * TP, S(0)), gN(3 * TP, S(0));
  int maxlast = 0;
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
  int32_t row_last[TS + 1] = {};  // the padding row's is 0
  for (int r = 0; r < TS; ++r) row_last[r] = *std::max_element(last + r * RS, last + r * RS + TS);
  const S near = S(st.near), mscale = S(st.far / (st.far - st.near));
  const S mder = S(st.far * st.near / (st.far - st.near));
  const int64_t b0 = B.offsets[tile];
#if FR_AVX2
  if constexpr (std::is_same<S, float>::value && !FISHER) {
    if (D <= MAX_D_AVX2) {
      backward_splats_avx2(B, D, fl, tx, ty, b0, maxlast, row_last, px, py, T, Pre, Tot, gA, gZ, gM, gM2, gMed,
                           last, medj, gF.data(), gN.data(), G, slots, st);
      return;
    }
  }
#endif
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
      int e = 0;
      for (int a1 = 0; a1 < NG; ++a1)
        for (int a2 = a1; a2 < NG; ++a2, ++e) {
          S acc = 0;
#pragma omp simd reduction(+ : acc)
          for (int p = p0; p < p1; ++p) acc += gg[a1][p] * gg[a2][p];
          slot[e] = acc;
        }
      slot[NSYM] = o2;
      slot[NSYM + 1] = w2;
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

template <typename S>
std::vector<torch::Tensor> backward_impl(torch::Tensor means, torch::Tensor U, torch::Tensor V,
                                         torch::Tensor n, torch::Tensor opac, torch::Tensor feats,
                                         torch::Tensor viewmats, torch::Tensor Ks, int64_t W, int64_t H,
                                         double near, double far, const Flags& fl,
                                         std::vector<torch::Tensor> fwd, std::vector<torch::Tensor> grads,
                                         bool fisher, RenderCache* cache) {
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
      fresh = bin_and_sort(own, groups, vis, f, int(D), st, g_stats);
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
    const int64_t nrec = int64_t(B.splat.size());
    g_stats.reduce += omp_get_wtime() - t0;
    t0 = omp_get_wtime();
    if (fisher) {
      S* fg = fis_geo.data_ptr<S>() + c * N * NSYM;
      S* fo = fis_o.data_ptr<S>() + c * N;
      S* fw = fis_w.data_ptr<S>() + c * N;
#pragma omp parallel for schedule(static)
      for (int64_t r = 0; r < nrec; ++r) {
        const int64_t i = B.splat[r];
        for (int e = 0; e < NSYM; ++e) fg[i * NSYM + e] = rows[size_t(r) * G + e];
        fo[i] = rows[size_t(r) * G + NSYM];
        fw[i] = rows[size_t(r) * G + NSYM + 1];
      }
      g_stats.chain += omp_get_wtime() - t0;
      continue;
    }
    S *gm = g_means.data_ptr<S>(), *gu = g_U.data_ptr<S>(), *gv = g_V.data_ptr<S>();
    S *gn = g_n.data_ptr<S>(), *go = g_op.data_ptr<S>();
    S* gf = g_feat.data_ptr<S>() + (shared ? 0 : c * N * D);
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
    g_stats.chain += omp_get_wtime() - t0;
  }
  if (fisher) return {fis_geo, fis_o, fis_w};
  return {g_means, g_U, g_V, g_n, g_op, g_feat};
}


// Increasing indices of the splats that pass project_splat's first test for one camera (with a
// float slack): every splat the camera can draw is among them. A caller that trains on one view (the mapper) works on
// these rows alone: the others get no gradient, so they stay undrawn for as long as the view does.
template <typename S>
torch::Tensor candidate_rows_impl(const torch::Tensor& means, const torch::Tensor& U, const torch::Tensor& V,
                                  const Camera& cam, const Settings& st) {
  const int64_t N = means.size(0);
  const Frustum fr = frustum_of(cam, st);
  const S *m = means.data_ptr<S>(), *u = U.data_ptr<S>(), *v = V.data_ptr<S>();
  const S tmag = S(std::fabs(cam.t[0]) + std::fabs(cam.t[1]) + std::fabs(cam.t[2]));
  std::vector<uint8_t> keep(N);
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < N; ++i) {
    S pc[3];
    camera_point(cam, m + 3 * i, pc);
    const S* p = m + 3 * i;
    const S slack = S(1e-5) * (S(1) + std::fabs(p[0]) + std::fabs(p[1]) + std::fabs(p[2]) + tmag);
    keep[i] = !sphere_outside(pc, sphere_radius(u + 3 * i, v + 3 * i) * S(1 + 1e-5), fr, st, slack);
  }
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

std::vector<torch::Tensor> forward(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                   torch::Tensor opac, torch::Tensor feats, torch::Tensor viewmats,
                                   torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                   bool normal, bool depth, bool dist, bool track, RenderCache* cache) {
  const Flags fl{normal, depth, dist, track || normal || depth || dist};
  if (means.scalar_type() == torch::kFloat64)
    return forward_impl<double>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, cache);
  return forward_impl<float>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, cache);
}

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

std::vector<torch::Tensor> backward(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                    torch::Tensor opac, torch::Tensor feats, torch::Tensor viewmats,
                                    torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                    bool normal, bool depth, bool dist,
                                    std::vector<torch::Tensor> fwd, std::vector<torch::Tensor> grads,
                                    bool fisher, RenderCache* cache) {
  const Flags fl{normal, depth, dist, true};
  if (means.scalar_type() == torch::kFloat64)
    return backward_impl<double>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, fwd, grads, fisher,
                                 cache);
  return backward_impl<float>(means, U, V, n, opac, feats, viewmats, Ks, W, H, near, far, fl, fwd, grads, fisher,
                              cache);
}

}  // namespace

void bind_rasterizer(pybind11::module_& m) {
  namespace py = pybind11;
  py::class_<RenderCache>(m, "RenderCache", "a single camera's projection and bins, kept by forward for backward")
      .def(py::init<>());
  // the last argument is a RenderCache or None: forward fills it, backward reads it
  m.def("forward", &forward, "2DGS forward for C cameras");
  m.def("backward", &backward, "2DGS backward (or FisherRF squared contributions) for C cameras");
  m.def("feature_sums", &feature_sums, "per-camera pixel sums of a two-sided splat feature, with a tail cut");
  m.def("candidate_rows", &candidate_rows, "indices of the splats one camera may draw (its frustum test)");
  m.def("num_threads", []() { return omp_get_max_threads(); });
  m.def("last_stats", []() {
    return std::map<std::string, double>{
        {"project_s", g_stats.project}, {"bin_s", g_stats.bin}, {"sort_s", g_stats.sort},
        {"blend_s", g_stats.blend}, {"reduce_s", g_stats.reduce}, {"chain_s", g_stats.chain},
        {"evals", double(g_stats.evals)}, {"blends", double(g_stats.blends)}, {"isects", double(g_stats.isects)},
        {"by_camera", double(g_stats.by_camera)}};
  }, "phase timings and pixel-splat evaluations of the last forward/backward call");
}

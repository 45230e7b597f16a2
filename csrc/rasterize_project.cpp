// Projection stage of the rasterizer: the splats grouped once per call for culling (SplatGroups),
// then per camera the frustum tests (of a group's sphere, then of each splat's) and the projection
// of the splats that pass: ray transform M = K [U_c | V_c | p_c], projected center, oriented
// normal, depth, and the pixel box the tiles are binned by (Projected, Visible).
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <vector>

#include "rasterize.h"

namespace raster {
namespace {

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

// ---------------------------------------------------------------- splat groups (once per call)

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

// The sphere around n spheres (center_of(i): a pointer to 3 coordinates, radius_of(i)): the box
// center of their centers, and a radius that holds each sphere, its center's offset scaled by `pad`.
template <typename Center, typename Radius>
void enclose(int64_t n, Center center_of, Radius radius_of, double pad, double* c) {
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = double(center_of(0)[a]);
  for (int64_t i = 1; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], double(center_of(i)[a]));
      hi[a] = std::max(hi[a], double(center_of(i)[a]));
    }
  for (int a = 0; a < 3; ++a) c[a] = 0.5 * (lo[a] + hi[a]);
  double r = 0;
  for (int64_t i = 0; i < n; ++i) {
    const auto* p = center_of(i);
    const double dx = p[0] - c[0], dy = p[1] - c[1], dz = p[2] - c[2];
    r = std::max(r, std::sqrt(dx * dx + dy * dy + dz * dz) * pad + double(radius_of(i)));
  }
  c[3] = r;
}

// Group k's sphere: its means' box center, and a radius that holds each splat's bounding sphere.
template <typename S>
void bound_group(SplatGroups<S>& g, int k) {
  const int64_t s0 = g.begin(k);
  enclose(g.end(k) - s0, [&](int64_t i) { return &g.mean[3 * (s0 + i)]; }, [&](int64_t i) { return g.rad[s0 + i]; },
          1.0, &g.sphere[4 * size_t(k)]);
}

// Block b's sphere: its groups' centers' box center, and a radius that holds each group's sphere,
// padded by 2e-4 of the group's offset so that a block group_outside culls has every group
// group_outside culls too: a group's test margin (1e-4 of a scale that grows by at most sqrt(3)
// times its offset from the block's center, less the radius gap) never outgrows the block's.
template <typename S>
void bound_block(SplatGroups<S>& g, int b) {
  const int k0 = b * BLOCK, k1 = std::min(g.groups(), k0 + BLOCK);
  const double* spheres = &g.sphere[4 * size_t(k0)];
  enclose(k1 - k0, [&](int64_t i) { return spheres + 4 * i; }, [&](int64_t i) { return spheres[4 * i + 3]; },
          1.0 + 2e-4, &g.block[4 * size_t(b)]);
}

// ---------------------------------------------------------------- frustum tests

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
// `slack`, which candidate_mask sets to cover the float rounding of the test (the compiler may fuse
// its multiply-adds differently there), so that it never drops a splat project_splat keeps.
template <typename S>
inline bool sphere_outside(const S* pc, S rad, const Frustum& fr, const Settings& st, S slack = S(0)) {
  if (!fr.pinhole) return false;
  bool out = !(pc[2] > S(st.near) - slack);
  for (int k = 0; k < 4; ++k)
    out = out || S(fr.planes[k][0]) * pc[k / 2] + S(fr.planes[k][1]) * pc[2] < -(rad + slack);
  return out;
}

// ---------------------------------------------------------------- projection of one camera

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

}  // namespace

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
    g.block.resize(4 * size_t(g.blocks()));
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
  if (spatial)
    for (int b = 0; b < g.blocks(); ++b) bound_block(g, b);
  return g;
}

template <typename S>
void project_camera(const SplatGroups<S>& G, const Camera& cam, const Settings& st, Projected<S>& P,
                    Visible& vis) {
  const Frustum fr = frustum_of(cam, st);
  vis.groups.clear();
  vis.tests = 0;
  if (fr.pinhole && G.culls()) {
    // the groups of the blocks that pass, in increasing order: those group_outside keeps
    for (int b = 0; b < G.blocks(); ++b) {
      ++vis.tests;
      if (group_outside(&G.block[4 * size_t(b)], cam, fr, st.near)) continue;
      const int k1 = std::min(G.groups(), (b + 1) * BLOCK);
      for (int k = b * BLOCK; k < k1; ++k) {
        ++vis.tests;
        if (!group_outside(&G.sphere[4 * size_t(k)], cam, fr, st.near)) vis.groups.push_back(k);
      }
    }
  } else {
    vis.groups.resize(G.groups());
    std::iota(vis.groups.begin(), vis.groups.end(), 0);
  }
  const int ng = int(vis.groups.size());
  vis.projected = 0;
  for (const int k : vis.groups) vis.projected += G.end(k) - G.begin(k);
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

template <typename S>
void write_radii(const SplatGroups<S>& G, const Visible& vis, const Projected<S>& P, int32_t* radii) {
  if (int(vis.groups.size()) < G.groups()) std::fill(radii, radii + G.N, 0);  // some were culled
  for (const int k : vis.groups)
    for (int64_t s = G.begin(k); s < G.end(k); ++s) radii[G.id[s]] = P.radii[s];
}

// A caller that trains on one view (the mapper) works on the rows of this mask alone: the others
// get no gradient, so they stay undrawn for as long as the view does.
template <typename S>
std::vector<uint8_t> candidate_mask(const S* m, const S* u, const S* v, int64_t N, const Camera& cam,
                                    const Settings& st) {
  const Frustum fr = frustum_of(cam, st);
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
  return keep;
}

template SplatGroups<float> group_splats(const float*, const float*, const float*, const float*, const float*,
                                         int64_t, bool);
template SplatGroups<double> group_splats(const double*, const double*, const double*, const double*,
                                          const double*, int64_t, bool);
template void project_camera(const SplatGroups<float>&, const Camera&, const Settings&, Projected<float>&,
                             Visible&);
template void project_camera(const SplatGroups<double>&, const Camera&, const Settings&, Projected<double>&,
                             Visible&);
template void write_radii(const SplatGroups<float>&, const Visible&, const Projected<float>&, int32_t*);
template void write_radii(const SplatGroups<double>&, const Visible&, const Projected<double>&, int32_t*);
template std::vector<uint8_t> candidate_mask(const float*, const float*, const float*, int64_t, const Camera&,
                                             const Settings&);
template std::vector<uint8_t> candidate_mask(const double*, const double*, const double*, int64_t, const Camera&,
                                             const Settings&);

}  // namespace raster

// The Fisher mode of the backward (FisherRF's squared per-pixel gradients): instead of the gradient
// of a loss, per splat the sums over pixels of products of its per-pixel gradient terms. The backward
// blend (rasterize_backward.cpp, backward_splats_generic<S, true>) computes the same per-pixel
// geometric terms as the plain backward (T_u, T_v, T_w and means2d: NG of them); per (tile, splat)
// slot this mode keeps the sums of their pairwise products (the upper triangle of the NG x NG outer
// product, NSYM entries), of dL/do^2 and of w^2. The slots are reduced per splat in tile order like
// the plain backward's, then written out by splat id.
#include <omp.h>

#include <cstdint>
#include <vector>

#include "rasterize.h"

namespace raster {

// Slot layout: NSYM outer-product entries (rows a1 <= a2), sum of dL/do^2, sum of w^2.
template <typename S>
void fisher_slot(const S (*gg)[TP], int p0, int p1, S o2, S w2, S* slot) {
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
}

template <typename S>
void fisher_rows(const Bins<S>& B, int G, const std::vector<S>& rows, S* fg, S* fo, S* fw) {
  const int64_t nrec = int64_t(B.splat.size());
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < nrec; ++r) {
    const int64_t i = B.splat[r];
    for (int e = 0; e < NSYM; ++e) fg[i * NSYM + e] = rows[size_t(r) * G + e];
    fo[i] = rows[size_t(r) * G + NSYM];
    fw[i] = rows[size_t(r) * G + NSYM + 1];
  }
}

template void fisher_slot(const float (*)[TP], int, int, float, float, float*);
template void fisher_slot(const double (*)[TP], int, int, double, double, double*);
template void fisher_rows(const Bins<float>&, int, const std::vector<float>&, float*, float*, float*);
template void fisher_rows(const Bins<double>&, int, const std::vector<double>&, double*, double*, double*);

}  // namespace raster

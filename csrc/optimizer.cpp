// Sparse Adam over the map's parameter rows (flightrecon/mapping/optimizer.py), one call per step.
//
// The visible rows are cut into blocks of kBlock. Per block, each row's step count is bumped and
// its bias corrections computed, then each parameter's rows are copied into component-major block
// arrays (gradient, moments, values), updated by one loop per component over the whole block and
// copied back. The update loops always run over all kBlock lanes (a short last block is padded with
// zeros), so every element takes the same vector code path and its rounding does not depend on its
// position in `visible`. Blocks are independent, so they run in parallel; rows must be unique.
//
// The update is computed in double and rounded to float once: a float g * g overflows for
// |g| > 1.8e19 (the step would then be 0 instead of ~lr) and underflows to subnormals for |g| < 1e-19,
// where flush-to-zero and approximate square roots turn 0 / (sqrt(0) + eps) into NaN. In double the
// result equals a float64 Adam's for every finite float gradient whose moments fit a float.

#include "bindings.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

constexpr int64_t kBlock = 128;
constexpr int64_t kMaxComponents = 4;

// One trained parameter: the leaves (updated at local rows) and its moments (at map rows).
struct Param {
  float* value;
  const float* grad;
  float* m;
  float* v;
  int64_t C;
  float lr;
};

struct Coeffs {
  double b1, b2, a1, a2, eps;
};

// One block of rows of a parameter: copied into component-major arrays, updated over all kBlock
// lanes, copied back. The copies stay scalar loops over the runtime C: a compile-time C lets GCC
// turn them into AVX-512 gathers, which made the step 40% slower on the EPYC it was measured on.
void update_block(const Param& p, int64_t cnt, const int64_t* local, const int64_t* global,
                  const double* step_size, const double* bc2_sqrt, const Coeffs& k) {
  const int64_t C = p.C;
  alignas(64) float g[kMaxComponents][kBlock], m[kMaxComponents][kBlock], v[kMaxComponents][kBlock],
      x[kMaxComponents][kBlock];
  for (int64_t i = 0; i < cnt; ++i) {
    for (int64_t c = 0; c < C; ++c) {
      g[c][i] = p.grad[local[i] * C + c];
      x[c][i] = p.value[local[i] * C + c];
      m[c][i] = p.m[global[i] * C + c];
      v[c][i] = p.v[global[i] * C + c];
    }
  }
  for (int64_t c = 0; c < C; ++c) {
    for (int64_t i = cnt; i < kBlock; ++i) g[c][i] = x[c][i] = m[c][i] = v[c][i] = 0.0f;
    float* gc = g[c];
    float* mc = m[c];
    float* vc = v[c];
    float* xc = x[c];
    const double lr = p.lr;
#pragma omp simd
    for (int64_t i = 0; i < kBlock; ++i) {
      const double gi = gc[i];
      const double mi = k.b1 * mc[i] + k.a1 * gi;
      const double vi = k.b2 * vc[i] + k.a2 * gi * gi;
      mc[i] = float(mi);
      vc[i] = float(vi);
      const double denom = std::sqrt(vi) / bc2_sqrt[i] + k.eps;
      xc[i] = float(xc[i] - lr * (mi * step_size[i] / denom));
    }
  }
  for (int64_t i = 0; i < cnt; ++i) {
    for (int64_t c = 0; c < C; ++c) {
      p.value[local[i] * C + c] = x[c][i];
      p.m[global[i] * C + c] = m[c][i];
      p.v[global[i] * C + c] = v[c][i];
    }
  }
}

// The step of the n leaf rows vis[] (map rows map_row[vis[i]], or vis[i] when map_row is null).
void adam_rows(const std::vector<Param>& params, int32_t* step, const int64_t* vis, int64_t n,
               const int64_t* map_row, double beta1, double beta2, double eps) {
  const Coeffs k{beta1, beta2, 1.0 - beta1, 1.0 - beta2, eps};
  const double log_b1 = std::log(beta1), log_b2 = std::log(beta2);
  const int64_t blocks = (n + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(static)
  for (int64_t b = 0; b < blocks; ++b) {
    const int64_t i0 = b * kBlock, cnt = std::min(kBlock, n - i0);
    int64_t local[kBlock], global[kBlock];
    alignas(64) double t[kBlock];
    alignas(64) double step_size[kBlock], bc2_sqrt[kBlock];
    for (int64_t i = 0; i < cnt; ++i) {
      local[i] = vis[i0 + i];
      global[i] = map_row ? map_row[local[i]] : local[i];
      t[i] = double(++step[global[i]]);
    }
    for (int64_t i = cnt; i < kBlock; ++i) t[i] = 1.0;
    // 1 - beta^t as -expm1(t log beta): 1 - 0.999^t loses ~5 digits to cancellation in float
    // for young splats; the vector expm1 also costs about half the vector pow
#pragma omp simd
    for (int64_t i = 0; i < kBlock; ++i) {
      step_size[i] = -1.0 / std::expm1(t[i] * log_b1);  // 1 / bias correction 1
      bc2_sqrt[i] = std::sqrt(-std::expm1(t[i] * log_b2));
    }
    for (const Param& p : params) {
      update_block(p, cnt, local, global, step_size, bc2_sqrt, k);
    }
  }
}

// ---- torch binding ----

// Rows of C floats: shape [rows] (C = 1) or [rows, C].
void check_float(const torch::Tensor& t, int64_t rows, int64_t C, const char* what) {
  TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == torch::kFloat32 && t.is_contiguous(),
              what, " must be a contiguous float32 CPU tensor");
  TORCH_CHECK(t.dim() >= 1 && t.dim() <= 2 && t.size(0) == rows && (t.dim() == 1 ? 1 : t.size(1)) == C,
              what, " has the wrong shape");
}

// Adam on the rows `visible` of the leaves `values` (with `grads`); the moments `ms`, `vs` and the
// step counts `steps` are the map's columns, at rows[visible] (or at visible when rows is None).
void adam_step(std::vector<torch::Tensor> values, std::vector<torch::Tensor> grads,
               std::vector<torch::Tensor> ms, std::vector<torch::Tensor> vs, std::vector<double> lrs,
               torch::Tensor steps, torch::Tensor visible, c10::optional<torch::Tensor> rows,
               double beta1, double beta2, double eps) {
  const size_t P = values.size();
  TORCH_CHECK(grads.size() == P && ms.size() == P && vs.size() == P && lrs.size() == P,
              "adam_step: one gradient, two moments and one lr per parameter");
  TORCH_CHECK(steps.device().is_cpu() && steps.scalar_type() == torch::kInt32 && steps.is_contiguous() &&
              steps.dim() == 1, "adam_step: steps must be a contiguous int32 CPU vector");
  TORCH_CHECK(visible.device().is_cpu() && visible.scalar_type() == torch::kInt64 && visible.is_contiguous() &&
              visible.dim() == 1, "adam_step: visible must be a contiguous int64 CPU vector");
  const int64_t N = steps.size(0);
  const int64_t n_local = rows ? rows->size(0) : N;
  if (rows) {
    TORCH_CHECK(rows->device().is_cpu() && rows->scalar_type() == torch::kInt64 && rows->is_contiguous() &&
                rows->dim() == 1, "adam_step: rows must be a contiguous int64 CPU vector");
  }
  std::vector<Param> params;
  for (size_t k = 0; k < P; ++k) {
    const int64_t C = values[k].dim() == 1 ? 1 : values[k].size(-1);
    TORCH_CHECK(C >= 1 && C <= kMaxComponents, "adam_step: a parameter has 1 to 4 components per row");
    check_float(values[k], n_local, C, "adam_step: a parameter");
    check_float(grads[k], n_local, C, "adam_step: a gradient");
    check_float(ms[k], N, C, "adam_step: a first moment");
    check_float(vs[k], N, C, "adam_step: a second moment");
    params.push_back({values[k].data_ptr<float>(), grads[k].data_ptr<float>(), ms[k].data_ptr<float>(),
                      vs[k].data_ptr<float>(), C, float(lrs[k])});
  }
  const int64_t n = visible.size(0);
  const int64_t* vis = visible.data_ptr<int64_t>();
  const int64_t* map_row = rows ? rows->data_ptr<int64_t>() : nullptr;
  int64_t bad = 0;
#pragma omp parallel for schedule(static) reduction(+ : bad)
  for (int64_t i = 0; i < n; ++i) {
    const int64_t l = vis[i];
    bad += (l < 0 || l >= n_local || (map_row && (map_row[l] < 0 || map_row[l] >= N))) ? 1 : 0;
  }
  TORCH_CHECK(bad == 0, "adam_step: a visible index or its map row is out of range");

  adam_rows(params, steps.data_ptr<int32_t>(), vis, n, map_row, beta1, beta2, eps);
}

}  // namespace

void bind_optimizer(pybind11::module_& m) {
  m.def("adam_step", &adam_step,
        "Sparse Adam step of the visible rows of several parameters, moments at the map's rows",
        pybind11::arg("values"), pybind11::arg("grads"), pybind11::arg("ms"), pybind11::arg("vs"),
        pybind11::arg("lrs"), pybind11::arg("steps"), pybind11::arg("visible"), pybind11::arg("rows"),
        pybind11::arg("beta1"), pybind11::arg("beta2"), pybind11::arg("eps"));
}

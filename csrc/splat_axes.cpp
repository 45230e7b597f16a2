// World-frame splat axes from quaternions and log-scales, and their backward.
//
// The rasterizer consumes U = s_u R e_u, V = s_v R e_v and n = R e_w (the statement is
// flightrecon/render/projection.py: splat_axes and quat_to_rotmat). Written in torch, the
// quaternion-to-matrix chain is ~30 elementwise nodes whose backward cost the mapper ~9 ms per
// iteration on 100k splats; here it is one pass over the splats each way.
#include <omp.h>

#include <cmath>

#include "bindings.h"

namespace {

constexpr double NORM_MIN = 1e-12;  // the torch statement's clamp of |q|

// Unit quaternion (w, x, y, z) from q and the norm it was divided by.
template <typename S>
inline S unit_quat(const S* q, S* u) {
  const S r = std::max(std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]), S(NORM_MIN));
  for (int k = 0; k < 4; ++k) u[k] = q[k] / r;
  return r;
}

template <typename S>
void axes_forward(const S* quats, const S* log_scales, int64_t N, S* U, S* V, S* n) {
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < N; ++i) {
    S q[4];
    unit_quat(quats + 4 * i, q);
    const S w = q[0], x = q[1], y = q[2], z = q[3];
    const S su = std::exp(log_scales[2 * i]), sv = std::exp(log_scales[2 * i + 1]);
    S* u = U + 3 * i;
    S* v = V + 3 * i;
    S* m = n + 3 * i;
    u[0] = (1 - 2 * (y * y + z * z)) * su;
    u[1] = 2 * (x * y + w * z) * su;
    u[2] = 2 * (x * z - w * y) * su;
    v[0] = 2 * (x * y - w * z) * sv;
    v[1] = (1 - 2 * (x * x + z * z)) * sv;
    v[2] = 2 * (y * z + w * x) * sv;
    m[0] = 2 * (x * z + w * y);
    m[1] = 2 * (y * z - w * x);
    m[2] = 1 - 2 * (x * x + y * y);
  }
}

// Gradients of quats and log_scales from those of U, V, n: through the rotation matrix's columns
// (G[r][c] = dL/dR[r][c]), the quaternion products, and the normalization q / |q|.
template <typename S>
void axes_backward(const S* quats, const S* log_scales, const S* gU, const S* gV, const S* gn, int64_t N,
                   S* g_quats, S* g_log_scales) {
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < N; ++i) {
    S q[4];
    const S r = unit_quat(quats + 4 * i, q);
    const S w = q[0], x = q[1], y = q[2], z = q[3];
    const S su = std::exp(log_scales[2 * i]), sv = std::exp(log_scales[2 * i + 1]);
    const S* gu = gU + 3 * i;
    const S* gv = gV + 3 * i;
    const S* gm = gn + 3 * i;
    const S R0[3] = {1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)};
    const S R1[3] = {2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)};
    g_log_scales[2 * i] = (gu[0] * R0[0] + gu[1] * R0[1] + gu[2] * R0[2]) * su;
    g_log_scales[2 * i + 1] = (gv[0] * R1[0] + gv[1] * R1[1] + gv[2] * R1[2]) * sv;
    const S G00 = gu[0] * su, G10 = gu[1] * su, G20 = gu[2] * su;
    const S G01 = gv[0] * sv, G11 = gv[1] * sv, G21 = gv[2] * sv;
    const S G02 = gm[0], G12 = gm[1], G22 = gm[2];
    const S gq[4] = {
        2 * (-z * G01 + y * G02 + z * G10 - x * G12 - y * G20 + x * G21),
        2 * (y * G01 + z * G02 + y * G10 - 2 * x * G11 - w * G12 + z * G20 + w * G21 - 2 * x * G22),
        2 * (-2 * y * G00 + x * G01 + w * G02 + x * G10 + z * G12 - w * G20 + z * G21 - 2 * y * G22),
        2 * (-2 * z * G00 - w * G01 + x * G02 + w * G10 - 2 * z * G11 + y * G12 + x * G20 + y * G21)};
    // d(q / r)/dq = (I - u u^T) / r where the norm is not clamped; 1 / r where it is
    const bool clamped = r <= S(NORM_MIN);
    const S dot = clamped ? S(0) : w * gq[0] + x * gq[1] + y * gq[2] + z * gq[3];
    for (int k = 0; k < 4; ++k) g_quats[4 * i + k] = (gq[k] - q[k] * dot) / r;
  }
}

void check(const torch::Tensor& quats, const torch::Tensor& log_scales) {
  TORCH_CHECK(quats.dim() == 2 && quats.size(1) == 4, "quats must be [N, 4]");
  TORCH_CHECK(log_scales.dim() == 2 && log_scales.size(1) == 2 && log_scales.size(0) == quats.size(0),
              "log_scales must be [N, 2]");
  TORCH_CHECK(quats.scalar_type() == log_scales.scalar_type(), "quats and log_scales must share a dtype");
  TORCH_CHECK(quats.is_contiguous() && log_scales.is_contiguous() && quats.device().is_cpu(),
              "contiguous CPU tensors expected");
}

std::vector<torch::Tensor> forward(torch::Tensor quats, torch::Tensor log_scales) {
  check(quats, log_scales);
  const int64_t N = quats.size(0);
  auto U = torch::empty({N, 3}, quats.options()), V = torch::empty_like(U), n = torch::empty_like(U);
  AT_DISPATCH_FLOATING_TYPES(quats.scalar_type(), "splat_axes_forward", [&] {
    axes_forward<scalar_t>(quats.data_ptr<scalar_t>(), log_scales.data_ptr<scalar_t>(), N, U.data_ptr<scalar_t>(),
                           V.data_ptr<scalar_t>(), n.data_ptr<scalar_t>());
  });
  return {U, V, n};
}

std::vector<torch::Tensor> backward(torch::Tensor quats, torch::Tensor log_scales, torch::Tensor gU,
                                    torch::Tensor gV, torch::Tensor gn) {
  check(quats, log_scales);
  const int64_t N = quats.size(0);
  for (const auto* g : {&gU, &gV, &gn})
    TORCH_CHECK(g->sizes() == torch::IntArrayRef({N, 3}) && g->is_contiguous() &&
                g->scalar_type() == quats.scalar_type(), "axis gradients must be contiguous [N, 3] of the quats' dtype");
  auto g_quats = torch::empty_like(quats), g_log_scales = torch::empty_like(log_scales);
  AT_DISPATCH_FLOATING_TYPES(quats.scalar_type(), "splat_axes_backward", [&] {
    axes_backward<scalar_t>(quats.data_ptr<scalar_t>(), log_scales.data_ptr<scalar_t>(), gU.data_ptr<scalar_t>(),
                            gV.data_ptr<scalar_t>(), gn.data_ptr<scalar_t>(), N, g_quats.data_ptr<scalar_t>(),
                            g_log_scales.data_ptr<scalar_t>());
  });
  return {g_quats, g_log_scales};
}

}  // namespace

void bind_splat_axes(pybind11::module_& m) {
  m.def("splat_axes_forward", &forward, "U, V, n [N,3] from quats [N,4] (any norm) and log_scales [N,2]");
  m.def("splat_axes_backward", &backward, "gradients of quats and log_scales from those of U, V, n");
}

// ActiveGS's exploration utility (flightrecon/active/baselines.py, VoxelMap.visible_unexplored): per
// camera, the number of distinct unexplored voxels its pixel rays pass before their first occupied
// voxel. Each ray is sampled at the given distances; a sample outside the grid counts nothing and
// blocks nothing. The torch statement of the same rule materializes every sample of every ray of
// every camera ([C, rays, samples, 3] in double); here a ray stops at its first occupied voxel and a
// per-thread stamp array counts each voxel once per camera.
//
// A sample point is center + dir * t, then floor((p - origin) / voxel), in double as in the torch
// statement; the compiler may fuse the multiply-add, which can move a sample that lies within one
// ulp of a voxel face to the neighbouring voxel.
#include <omp.h>

#include <cmath>
#include <vector>

#include "bindings.h"

namespace {

torch::Tensor count_unexplored(torch::Tensor dirs, torch::Tensor centers, torch::Tensor samples,
                               torch::Tensor origin, torch::Tensor dims, double voxel, torch::Tensor occupied,
                               torch::Tensor touched) {
  TORCH_CHECK(dirs.dim() == 3 && dirs.size(2) == 3 && dirs.scalar_type() == torch::kFloat64,
              "dirs must be [C, R, 3] float64");
  TORCH_CHECK(centers.dim() == 2 && centers.size(0) == dirs.size(0) && centers.size(1) == 3 &&
                  centers.scalar_type() == torch::kFloat64,
              "centers must be [C, 3] float64, one per camera of dirs");
  TORCH_CHECK(samples.dim() == 1 && samples.scalar_type() == torch::kFloat64, "samples must be [S] float64");
  TORCH_CHECK(origin.numel() == 3 && origin.scalar_type() == torch::kFloat64, "origin must be 3 float64");
  TORCH_CHECK(dims.numel() == 3 && dims.scalar_type() == torch::kInt64, "dims must be 3 int64");
  TORCH_CHECK(voxel > 0, "voxel must be > 0");
  const int64_t n_vox = dims[0].item<int64_t>() * dims[1].item<int64_t>() * dims[2].item<int64_t>();
  TORCH_CHECK(occupied.scalar_type() == torch::kBool && touched.scalar_type() == torch::kBool &&
                  occupied.numel() == n_vox && touched.numel() == n_vox,
              "occupied and touched must be bool with one entry per voxel");
  dirs = dirs.contiguous();
  centers = centers.contiguous();
  samples = samples.contiguous();
  occupied = occupied.contiguous();
  touched = touched.contiguous();
  const int64_t C = dirs.size(0), R = dirs.size(1), S = samples.size(0);
  const double* d = dirs.data_ptr<double>();
  const double* ctr = centers.data_ptr<double>();
  const double* t = samples.data_ptr<double>();
  const double o[3] = {origin[0].item<double>(), origin[1].item<double>(), origin[2].item<double>()};
  const int64_t dm[3] = {dims[0].item<int64_t>(), dims[1].item<int64_t>(), dims[2].item<int64_t>()};
  const bool* occ = occupied.data_ptr<bool>();
  const bool* seen = touched.data_ptr<bool>();
  auto counts = torch::zeros({C}, torch::kInt64);
  int64_t* out = counts.data_ptr<int64_t>();
#pragma omp parallel
  {
    std::vector<int64_t> stamp(size_t(n_vox), -1);  // the last camera that counted each voxel
#pragma omp for schedule(dynamic, 1)
    for (int64_t c = 0; c < C; ++c) {
      int64_t count = 0;
      const double* cc = ctr + 3 * c;
      for (int64_t r = 0; r < R; ++r) {
        const double* dr = d + 3 * (c * R + r);
        for (int64_t k = 0; k < S; ++k) {
          int64_t ijk[3];
          bool inside = true;
          for (int q = 0; q < 3; ++q) {
            const double p = cc[q] + dr[q] * t[k];
            const double f = std::floor((p - o[q]) / voxel);
            inside = inside && f >= 0 && f < double(dm[q]);  // false for NaN: never cast out of range
            ijk[q] = inside ? int64_t(f) : 0;
          }
          if (!inside) continue;
          const int64_t v = (ijk[0] * dm[1] + ijk[1]) * dm[2] + ijk[2];
          if (occ[v]) break;
          if (!seen[v] && stamp[size_t(v)] != c) {
            stamp[size_t(v)] = c;
            ++count;
          }
        }
      }
      out[c] = count;
    }
  }
  return counts;
}

}  // namespace

void bind_voxel_rays(pybind11::module_& m) {
  m.def("count_unexplored", &count_unexplored,
        "per camera, distinct unexplored voxels its rays [C,R,3] from centers [C,3], sampled at distances [S], "
        "pass before their first occupied voxel (grid: origin, dims, voxel; occupied and touched per voxel)");
}

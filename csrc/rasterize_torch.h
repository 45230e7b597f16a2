// The rasterizer's torch-facing functions: each direction's entry point is defined in its stage file
// (after the *_impl it dispatches to by dtype) and bound to Python in rasterize.cpp. The stage
// files that take no tensors include only rasterize.h.
#pragma once

#include <torch/extension.h>

#include <vector>

#include "rasterize.h"

namespace raster {

// rasterize.cpp: camera c of viewmats [C, 4, 4] (world to camera) and Ks [C, 3, 3], in double.
Camera camera_of(const torch::Tensor& viewmats, const torch::Tensor& Ks, int64_t c);
// rasterize.cpp: the per-camera tile flags of keep_tiles (uint8 [C, tiles], checked), or null when
// it is empty (every tile).
const uint8_t* tile_flags(const torch::Tensor& keep_tiles, int64_t C, int64_t W, int64_t H);

// rasterize_forward.cpp
std::vector<torch::Tensor> forward(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                   torch::Tensor opac, torch::Tensor feats, torch::Tensor viewmats,
                                   torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                   bool normal, bool depth, bool dist, bool track, torch::Tensor keep_tiles,
                                   RenderCache* cache);

// rasterize_backward.cpp
std::vector<torch::Tensor> backward(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                    torch::Tensor opac, torch::Tensor feats, torch::Tensor viewmats,
                                    torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                    bool normal, bool depth, bool dist,
                                    std::vector<torch::Tensor> fwd, std::vector<torch::Tensor> grads,
                                    bool fisher, torch::Tensor keep_tiles, RenderCache* cache);

// rasterize_feature_sums.cpp
std::vector<torch::Tensor> feature_sums(torch::Tensor means, torch::Tensor U, torch::Tensor V, torch::Tensor n,
                                        torch::Tensor opac, torch::Tensor sided, torch::Tensor viewmats,
                                        torch::Tensor Ks, int64_t W, int64_t H, double near, double far,
                                        double w_min, bool weighted, double floor);

}  // namespace raster

// Each source file of the extension adds its functions to the one Python module (module.cpp).
#pragma once

#include <torch/extension.h>

void bind_rasterizer(pybind11::module_& m);
void bind_splat_axes(pybind11::module_& m);
void bind_optimizer(pybind11::module_& m);
void bind_image_ops(pybind11::module_& m);

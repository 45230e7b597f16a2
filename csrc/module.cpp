// The extension's Python module: the functions of every source file in csrc/.
#include "bindings.h"

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  bind_rasterizer(m);
  bind_splat_axes(m);
  bind_optimizer(m);
  bind_image_ops(m);
}

// World-frame splat axes from quaternions and log-scales (flightrecon/render/projection.py).
#include "bindings.h"

void bind_splat_axes(pybind11::module_& m) {}

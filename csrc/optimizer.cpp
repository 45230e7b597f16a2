// Sparse Adam over the map's parameter rows (flightrecon/mapping/optimizer.py).
#include "bindings.h"

void bind_optimizer(pybind11::module_& m) {}

// The `_native` Python module: each op folder of csrc/ registers its functions here.
#include <omp.h>

#include "bindings.h"

namespace nb = nanobind;

NB_MODULE(_native, m) {
    m.doc() = "surgsplat native CPU kernels (C++17, OpenMP)";
    // Autograd graphs alive at interpreter exit may still hold kernel state; that is no leak.
    nb::set_leak_warnings(false);
    m.def("max_threads", [] { return omp_get_max_threads(); }, "OpenMP threads the kernels use.");
    bind_rasterize(m);
    bind_hexplane(m);
    bind_blur(m);
    bind_project(m);
}

// Python bindings of surgsplat's native CPU kernels.
#include <nanobind/nanobind.h>

NB_MODULE(_native, m) {
    m.doc() = "surgsplat native CPU kernels (C++17, OpenMP)";
}

// Python binding of the benchmarks' limit probe.
#include <nanobind/nanobind.h>

#include <stdexcept>

#include "bindings.h"
#include "probe/probe.h"

namespace nb = nanobind;

namespace {

double probe(int64_t tiles, int64_t gaussians, int64_t channels) {
    if (tiles < 1 || gaussians < 1 || channels < 1)
        throw std::invalid_argument("composite_probe: tiles, gaussians and channels must be >= 1");
    nb::gil_scoped_release unlocked;
    return surgsplat::composite_probe(tiles, gaussians, channels);
}

}  // namespace

static void bind_probe(nb::module_& m) {
    m.def("composite_probe", &probe, nb::arg("tiles"), nb::arg("gaussians"), nb::arg("channels"),
          "Limit probe: composites `gaussians` Gaussians over every pixel of `tiles` 16x16 "
          "tiles with the kernels' arithmetic and nothing else (tiles * gaussians * 256 "
          "evaluations); returns a checksum.");
}

static const OpBinding binding(&bind_probe);

// Python bindings of the HexPlane sampler. Planes come as one flat list, six per scale in the
// order xy, xz, yz, xt, yt, zt, each [features, height, width] with height, width >= 2.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/vector.h>

#include <utility>
#include <vector>

#include "bindings.h"
#include "hexplane/common.h"

namespace nb = nanobind;
using surgsplat::PlaneView;
using surgsplat::Slabs;

namespace {

Slabs check_planes(const std::vector<In<float>>& planes) {
    if (planes.empty() || planes.size() % surgsplat::kPlanesPerScale != 0)
        throw std::invalid_argument("planes: expected six planes per scale, got " +
                                    std::to_string(planes.size()));
    std::vector<PlaneView> views;
    const size_t features = planes[0].ndim() == 3 ? planes[0].shape(0) : 0;
    for (size_t p = 0; p < planes.size(); ++p) {
        const In<float>& plane = planes[p];
        if (plane.ndim() != 3 || plane.shape(0) != features || features == 0 ||
            plane.shape(1) < 2 || plane.shape(2) < 2)
            throw std::invalid_argument(
                "planes[" + std::to_string(p) + "]: expected [F, H, W] with the same F > 0 as "
                "planes[0] and H, W >= 2");
        views.push_back({plane.data(), static_cast<int64_t>(plane.shape(1)),
                         static_cast<int64_t>(plane.shape(2))});
    }
    return Slabs(std::move(views), static_cast<int64_t>(features));
}

size_t check_coords(const In<float>& coords) {
    if (coords.ndim() != 2 || coords.shape(1) != surgsplat::kAxes)
        throw std::invalid_argument("coords: expected shape [N, 4] (x, y, z, t)");
    return coords.shape(0);
}

size_t output_width(const Slabs& slabs) {
    return slabs.planes.size() / surgsplat::kPlanesPerScale * slabs.features;
}

void forward(In<float> coords, std::vector<In<float>> planes, Out<float> out) {
    const size_t n = check_coords(coords);
    const Slabs slabs = check_planes(planes);
    expect_size(out, n * output_width(slabs), "out");
    nb::gil_scoped_release unlocked;
    surgsplat::hexplane_forward(coords.data(), static_cast<int64_t>(n), slabs, out.data());
}

void backward(In<float> coords, std::vector<In<float>> planes, In<float> grad_out,
              Out<float> grad_coords, std::vector<Out<float>> grad_planes) {
    const size_t n = check_coords(coords);
    const Slabs slabs = check_planes(planes);
    expect_size(grad_out, n * output_width(slabs), "grad_out");
    expect_size(grad_coords, n * surgsplat::kSpaceAxes, "grad_coords");
    if (grad_planes.size() != planes.size())
        throw std::invalid_argument("grad_planes: expected one array per plane");
    std::vector<float*> targets;
    for (size_t p = 0; p < planes.size(); ++p) {
        expect_size(grad_planes[p], planes[p].size(), "grad_planes[i]");
        targets.push_back(grad_planes[p].data());
    }
    nb::gil_scoped_release unlocked;
    surgsplat::hexplane_backward(coords.data(), static_cast<int64_t>(n), slabs,
                                 grad_out.data(), grad_coords.data(), targets);
}

}  // namespace

static void bind_hexplane(nb::module_& m) {
    m.def("hexplane_forward", &forward, nb::arg("coords"), nb::arg("planes"), nb::arg("out"),
          "Per scale, the product of the six bilinearly sampled planes (align_corners=True, "
          "border clamped), scales concatenated: coords [N, 4] -> out [N, scales * F].");
    m.def("hexplane_backward", &backward, nb::arg("coords"), nb::arg("planes"),
          nb::arg("grad_out"), nb::arg("grad_coords"), nb::arg("grad_planes"),
          "Gradients of hexplane_forward given grad_out [N, scales * F]: grad_coords [N, 3] "
          "(x, y, z; time gets none) and every plane's gradient, both overwritten.");
}

static const OpBinding binding(&bind_hexplane);

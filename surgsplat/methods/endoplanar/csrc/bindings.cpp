// Python bindings of the normal-consistency kernels.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>

#include <optional>
#include <utility>

#include "bindings.h"
#include "normals.h"

namespace nb = nanobind;

namespace {

struct Size {
    size_t height, width;
};

// The image size, after checking every input's shape.
Size check_inputs(const In<float>& depth, const In<float>& normals, const In<float>& ray_x,
                  const In<float>& ray_y, const In<bool>& mask,
                  const std::optional<In<float>>& weights) {
    if (depth.ndim() != 2) throw std::invalid_argument("depth: expected shape [H, W]");
    const Size s{depth.shape(0), depth.shape(1)};
    expect_size(normals, 3 * s.height * s.width, "normals");
    expect_size(ray_x, s.width, "ray_x");
    expect_size(ray_y, s.height, "ray_y");
    expect_size(mask, s.height * s.width, "mask");
    if (weights) expect_size(*weights, s.height * s.width, "weights");
    return s;
}

std::pair<double, int64_t> forward(In<float> depth, In<float> normals, In<float> ray_x,
                                   In<float> ray_y, In<bool> mask,
                                   std::optional<In<float>> weights) {
    const Size s = check_inputs(depth, normals, ray_x, ray_y, mask, weights);
    nb::gil_scoped_release unlocked;
    const surgsplat::NormalConsistency result = surgsplat::normal_consistency_forward(
        depth.data(), normals.data(), ray_x.data(), ray_y.data(), mask.data(),
        weights ? weights->data() : nullptr, s.height, s.width);
    return {result.sum, result.count};
}

void backward(In<float> depth, In<float> normals, In<float> ray_x, In<float> ray_y,
              In<bool> mask, std::optional<In<float>> weights, float grad_sum,
              std::optional<Out<float>> grad_depth, std::optional<Out<float>> grad_normals) {
    const Size s = check_inputs(depth, normals, ray_x, ray_y, mask, weights);
    if (grad_depth) expect_size(*grad_depth, depth.size(), "grad_depth");
    if (grad_normals) expect_size(*grad_normals, normals.size(), "grad_normals");
    nb::gil_scoped_release unlocked;
    surgsplat::normal_consistency_backward(
        depth.data(), normals.data(), ray_x.data(), ray_y.data(), mask.data(),
        weights ? weights->data() : nullptr, s.height, s.width, grad_sum,
        grad_depth ? grad_depth->data() : nullptr, grad_normals ? grad_normals->data() : nullptr);
}

}  // namespace

static void bind_normals(nb::module_& m) {
    m.def("normal_consistency_forward", &forward, nb::arg("depth"), nb::arg("normals"),
          nb::arg("ray_x"), nb::arg("ray_y"), nb::arg("mask"), nb::arg("weights").none(),
          "(sum, count) of EndoPlanar's normal consistency between the rendered normals "
          "[H, W, 3] and the normals of the depth [H, W] back-projected along the rays "
          "(ray_x [W], ray_y [H], 1), over the interior pixels of mask [H, W] with valid depth "
          "normals, each weighted by weights [H, W] (None: ones); see normals.h.");
    m.def("normal_consistency_backward", &backward, nb::arg("depth"), nb::arg("normals"),
          nb::arg("ray_x"), nb::arg("ray_y"), nb::arg("mask"), nb::arg("weights").none(),
          nb::arg("grad_sum"), nb::arg("grad_depth").none(), nb::arg("grad_normals").none(),
          "Gradients of grad_sum times the forward's sum with respect to depth [H, W] and "
          "normals [H, W, 3], each overwritten unless None.");
}

static const OpBinding binding(&bind_normals);

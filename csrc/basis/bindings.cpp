// Python bindings of the Gaussian-basis deformation kernels.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <string>

#include "basis/basis.h"
#include "bindings.h"

namespace nb = nanobind;

namespace {

struct BasisShape {
    size_t n, channels, basis;
};

BasisShape check_inputs(const In<float>& weights, const In<float>& centres,
                        const In<float>& log_widths) {
    if (weights.ndim() != 3 || weights.shape(2) < 1 ||
        static_cast<int64_t>(weights.shape(2)) > surgsplat::kMaxBasisFunctions)
        throw std::invalid_argument(
            "weights: expected shape [N, D, B] with 1 <= B <= " +
            std::to_string(surgsplat::kMaxBasisFunctions));
    const BasisShape shape{weights.shape(0), weights.shape(1), weights.shape(2)};
    expect_size(centres, shape.n * shape.basis, "centres");
    expect_size(log_widths, shape.n * shape.basis, "log_widths");
    return shape;
}

void forward(In<float> weights, In<float> centres, In<float> log_widths, float t,
             Out<float> out) {
    const BasisShape s = check_inputs(weights, centres, log_widths);
    expect_size(out, s.n * s.channels, "out");
    nb::gil_scoped_release unlocked;
    surgsplat::gaussian_basis_forward(weights.data(), centres.data(), log_widths.data(), s.n,
                                      s.channels, s.basis, t, out.data());
}

void backward(In<float> weights, In<float> centres, In<float> log_widths, float t,
              In<float> grad_out, Out<float> grad_weights, Out<float> grad_centres,
              Out<float> grad_log_widths) {
    const BasisShape s = check_inputs(weights, centres, log_widths);
    expect_size(grad_out, s.n * s.channels, "grad_out");
    expect_size(grad_weights, s.n * s.channels * s.basis, "grad_weights");
    expect_size(grad_centres, s.n * s.basis, "grad_centres");
    expect_size(grad_log_widths, s.n * s.basis, "grad_log_widths");
    nb::gil_scoped_release unlocked;
    surgsplat::gaussian_basis_backward(weights.data(), centres.data(), log_widths.data(), s.n,
                                       s.channels, s.basis, t, grad_out.data(),
                                       grad_weights.data(), grad_centres.data(),
                                       grad_log_widths.data());
}

}  // namespace

static void bind_gaussian_basis(nb::module_& m) {
    m.def("gaussian_basis_forward", &forward, nb::arg("weights"), nb::arg("centres"),
          nb::arg("log_widths"), nb::arg("t"), nb::arg("out"),
          "Deformation channels out [N, D] = sum_b weights [N, D, B] exp(-z^2 / 2), "
          "z = (t - centres [N, B]) exp(-log_widths [N, B]).");
    m.def("gaussian_basis_backward", &backward, nb::arg("weights"), nb::arg("centres"),
          nb::arg("log_widths"), nb::arg("t"), nb::arg("grad_out"), nb::arg("grad_weights"),
          nb::arg("grad_centres"), nb::arg("grad_log_widths"),
          "Gradients of gaussian_basis_forward given grad_out [N, D], all overwritten.");
}

static const OpBinding binding(&bind_gaussian_basis);

// Python bindings of the spherical-harmonic colour kernels.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <string>

#include "bindings.h"
#include "sh/sh.h"

namespace nb = nanobind;

namespace {

// The number of coefficients per Gaussian, after checking every input's shape.
size_t check_inputs(const In<float>& coeffs, const In<float>& means, const In<float>& centre,
                    int degree) {
    if (degree < 0 || degree > surgsplat::kMaxShDegree)
        throw std::invalid_argument("degree: expected 0 .. 3, got " + std::to_string(degree));
    const size_t used = static_cast<size_t>((degree + 1) * (degree + 1));
    if (coeffs.ndim() != 3 || coeffs.shape(1) < used || coeffs.shape(2) != 3)
        throw std::invalid_argument("coeffs: expected shape [N, K >= " + std::to_string(used) +
                                    ", 3]");
    expect_size(means, coeffs.shape(0) * 3, "means");
    expect_size(centre, 3, "centre");
    return coeffs.shape(1);
}

void forward(In<float> coeffs, In<float> means, In<float> centre, int degree, Out<float> rgb) {
    const size_t num_coeffs = check_inputs(coeffs, means, centre, degree);
    const size_t n = coeffs.shape(0);
    expect_size(rgb, 3 * n, "rgb");
    nb::gil_scoped_release unlocked;
    surgsplat::sh_forward(coeffs.data(), num_coeffs, means.data(), n, centre.data(), degree,
                          rgb.data());
}

void backward(In<float> coeffs, In<float> means, In<float> centre, int degree,
              In<float> grad_rgb, Out<float> grad_coeffs, Out<float> grad_means) {
    const size_t num_coeffs = check_inputs(coeffs, means, centre, degree);
    const size_t n = coeffs.shape(0);
    expect_size(grad_rgb, 3 * n, "grad_rgb");
    expect_size(grad_coeffs, coeffs.size(), "grad_coeffs");
    expect_size(grad_means, 3 * n, "grad_means");
    nb::gil_scoped_release unlocked;
    surgsplat::sh_backward(coeffs.data(), num_coeffs, means.data(), n, centre.data(), degree,
                           grad_rgb.data(), grad_coeffs.data(), grad_means.data());
}

}  // namespace

static void bind_sh(nb::module_& m) {
    m.def("sh_forward", &forward, nb::arg("coeffs"), nb::arg("means"), nb::arg("centre"),
          nb::arg("degree"), nb::arg("rgb"),
          "Colour rgb [N, 3] of SH coefficients [N, K, 3] seen from centre [3] (see sh.py).");
    m.def("sh_backward", &backward, nb::arg("coeffs"), nb::arg("means"), nb::arg("centre"),
          nb::arg("degree"), nb::arg("grad_rgb"), nb::arg("grad_coeffs"),
          nb::arg("grad_means"),
          "Gradients of sh_forward given grad_rgb [N, 3]: grad_coeffs [N, K, 3] and "
          "grad_means [N, 3], both overwritten.");
}

static const OpBinding binding(&bind_sh);

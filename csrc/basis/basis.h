// Gaussian-basis deformation channels (surgsplat/fields/gaussian_basis.py), forward and backward.
// Per Gaussian i, channel d and basis function b:
//   inv_sigma = exp(-log_width[i, b]),  z = (t - centre[i, b]) inv_sigma,
//   basis[i, b] = exp(-z^2 / 2),        out[i, d] = sum_b weights[i, d, b] basis[i, b].
// Nothing is shared between Gaussians: both passes are one parallel loop over blocks of them. The
// basis of a block is evaluated as one flat run of [block, B] values, 16 lanes at a time, with
// simd.h's pow2 for both exps; the backward evaluates it again instead of storing it.
#pragma once

#include <cstdint>

namespace surgsplat {

// Basis functions per Gaussian the kernels accept (a block's scratch lives on the stack).
constexpr int64_t kMaxBasisFunctions = 256;

// weights [n, channels, basis], centres [n, basis], log_widths [n, basis] -> out [n, channels].
void gaussian_basis_forward(const float* weights, const float* centres, const float* log_widths,
                            int64_t n, int64_t channels, int64_t basis, float t, float* out);

// Gradients of a scalar loss with respect to weights, centres and log_widths (overwritten), given
// its gradient grad_out [n, channels] with respect to out.
void gaussian_basis_backward(const float* weights, const float* centres,
                             const float* log_widths, int64_t n, int64_t channels,
                             int64_t basis, float t, const float* grad_out,
                             float* grad_weights, float* grad_centres, float* grad_log_widths);

}  // namespace surgsplat

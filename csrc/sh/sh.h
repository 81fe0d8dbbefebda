// View-dependent colour of real spherical harmonics (surgsplat/render/sh.py), forward and
// backward, one Gaussian per loop iteration. Per Gaussian i, seen from the camera centre c:
//   d = normalize(mean_i - c)  (torch.nn.functional.normalize: divided by max(|v|, 1e-12)),
//   rgb[i, ch] = max(sum_{k < (degree+1)^2} Y_k(d) coeffs[i, k, ch] + 0.5, 0),
// with the 3DGS convention's real basis Y_k up to degree 3. The backward gives the gradients of
// the coefficients and of the means (through the direction).
#pragma once

#include <cstdint>

namespace surgsplat {

constexpr int kMaxShDegree = 3;

// coeffs [n, num_coeffs, 3] (num_coeffs >= (degree+1)^2; only the first (degree+1)^2 are used),
// means [n, 3], centre [3] -> rgb [n, 3].
void sh_forward(const float* coeffs, int64_t num_coeffs, const float* means, int64_t n,
                const float* centre, int degree, float* rgb);

// Gradients of a scalar loss with respect to coeffs [n, num_coeffs, 3] (zero for the unused
// coefficients) and means [n, 3], both overwritten, given grad_rgb [n, 3].
void sh_backward(const float* coeffs, int64_t num_coeffs, const float* means, int64_t n,
                 const float* centre, int degree, const float* grad_rgb, float* grad_coeffs,
                 float* grad_means);

}  // namespace surgsplat

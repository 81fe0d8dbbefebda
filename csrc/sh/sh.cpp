// Spherical-harmonic colour; see sh.h. The constants are sh.py's SH_C0 .. SH_C3.
#include "sh/sh.h"

#include <algorithm>
#include <cmath>

namespace surgsplat {
namespace {

constexpr int kMaxCoeffs = (kMaxShDegree + 1) * (kMaxShDegree + 1);
constexpr float kNormEps = 1e-12f;  // torch.nn.functional.normalize's eps

constexpr float C0 = 0.28209479177387814f;
constexpr float C1 = 0.4886025119029199f;
constexpr float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f,
                         -1.0925484305920792f, 0.5462742152960396f};
constexpr float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f,
                         0.3731763325901154f, -0.4570457994644658f, 1.445305721320277f,
                         -0.5900435899266435f};

// The unit direction from the camera centre to a mean, and the length it was divided by.
struct ViewDirection {
    float x, y, z, length;
};

inline ViewDirection view_direction(const float* mean, const float* centre) {
    const float vx = mean[0] - centre[0], vy = mean[1] - centre[1], vz = mean[2] - centre[2];
    const float length = std::max(std::sqrt(vx * vx + vy * vy + vz * vz), kNormEps);
    return {vx / length, vy / length, vz / length, length};
}

// The basis values Y_0 .. Y_{(degree+1)^2 - 1} at direction d.
inline void sh_values(int degree, const ViewDirection& d, float* Y) {
    const float x = d.x, y = d.y, z = d.z;
    Y[0] = C0;
    if (degree < 1) return;
    Y[1] = -C1 * y;
    Y[2] = C1 * z;
    Y[3] = -C1 * x;
    if (degree < 2) return;
    const float xx = x * x, yy = y * y, zz = z * z;
    Y[4] = C2[0] * x * y;
    Y[5] = C2[1] * y * z;
    Y[6] = C2[2] * (2.0f * zz - xx - yy);
    Y[7] = C2[3] * x * z;
    Y[8] = C2[4] * (xx - yy);
    if (degree < 3) return;
    Y[9] = C3[0] * y * (3.0f * xx - yy);
    Y[10] = C3[1] * x * y * z;
    Y[11] = C3[2] * y * (4.0f * zz - xx - yy);
    Y[12] = C3[3] * z * (2.0f * zz - 3.0f * xx - 3.0f * yy);
    Y[13] = C3[4] * x * (4.0f * zz - xx - yy);
    Y[14] = C3[5] * z * (xx - yy);
    Y[15] = C3[6] * x * (xx - 3.0f * yy);
}

// The gradient (gx, gy, gz) with respect to the direction of sum_k s_k Y_k(d).
inline void sh_direction_gradient(int degree, const ViewDirection& d, const float* s, float* g) {
    const float x = d.x, y = d.y, z = d.z;
    float gx = 0.0f, gy = 0.0f, gz = 0.0f;
    if (degree >= 1) {
        gx -= C1 * s[3];
        gy -= C1 * s[1];
        gz += C1 * s[2];
    }
    if (degree >= 2) {
        const float a = C2[0] * s[4], b = C2[1] * s[5], c = C2[2] * s[6], e = C2[3] * s[7],
                    f = C2[4] * s[8];
        gx += a * y - 2.0f * c * x + e * z + 2.0f * f * x;
        gy += a * x + b * z - 2.0f * c * y - 2.0f * f * y;
        gz += b * y + 4.0f * c * z + e * x;
    }
    if (degree >= 3) {
        const float xx = x * x, yy = y * y, zz = z * z;
        const float s9 = C3[0] * s[9], s10 = C3[1] * s[10], s11 = C3[2] * s[11],
                    s12 = C3[3] * s[12], s13 = C3[4] * s[13], s14 = C3[5] * s[14],
                    s15 = C3[6] * s[15];
        gx += s9 * 6.0f * x * y + s10 * y * z - s11 * 2.0f * x * y - s12 * 6.0f * x * z +
              s13 * (4.0f * zz - 3.0f * xx - yy) + s14 * 2.0f * x * z +
              s15 * (3.0f * xx - 3.0f * yy);
        gy += s9 * (3.0f * xx - 3.0f * yy) + s10 * x * z + s11 * (4.0f * zz - xx - 3.0f * yy) -
              s12 * 6.0f * y * z - s13 * 2.0f * x * y - s14 * 2.0f * y * z - s15 * 6.0f * x * y;
        gz += s10 * x * y + s11 * 8.0f * y * z + s12 * (6.0f * zz - 3.0f * xx - 3.0f * yy) +
              s13 * 8.0f * x * z + s14 * (xx - yy);
    }
    g[0] = gx;
    g[1] = gy;
    g[2] = gz;
}

}  // namespace

void sh_forward(const float* coeffs, int64_t num_coeffs, const float* means, int64_t n,
                const float* centre, int degree, float* rgb) {
    const int used = (degree + 1) * (degree + 1);
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        float Y[kMaxCoeffs];
        sh_values(degree, view_direction(means + 3 * i, centre), Y);
        const float* c = coeffs + i * num_coeffs * 3;
        for (int ch = 0; ch < 3; ++ch) {
            float sum = 0.0f;
            for (int k = 0; k < used; ++k) sum += Y[k] * c[3 * k + ch];
            rgb[3 * i + ch] = std::max(sum + 0.5f, 0.0f);
        }
    }
}

void sh_backward(const float* coeffs, int64_t num_coeffs, const float* means, int64_t n,
                 const float* centre, int degree, const float* grad_rgb, float* grad_coeffs,
                 float* grad_means) {
    const int used = (degree + 1) * (degree + 1);
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const ViewDirection d = view_direction(means + 3 * i, centre);
        float Y[kMaxCoeffs];
        sh_values(degree, d, Y);
        const float* c = coeffs + i * num_coeffs * 3;
        // The clamp at 0 passes the gradient where the unclamped colour is >= 0 (torch's rule).
        float g[3];
        for (int ch = 0; ch < 3; ++ch) {
            float sum = 0.0f;
            for (int k = 0; k < used; ++k) sum += Y[k] * c[3 * k + ch];
            g[ch] = sum + 0.5f >= 0.0f ? grad_rgb[3 * i + ch] : 0.0f;
        }
        float* gc = grad_coeffs + i * num_coeffs * 3;
        float s[kMaxCoeffs];  // d loss / d Y_k
        for (int k = 0; k < used; ++k) {
            s[k] = 0.0f;
            for (int ch = 0; ch < 3; ++ch) {
                gc[3 * k + ch] = Y[k] * g[ch];
                s[k] += g[ch] * c[3 * k + ch];
            }
        }
        std::fill(gc + 3 * used, gc + 3 * num_coeffs, 0.0f);
        // Through d = v / max(|v|, eps): (I - d d^T) / |v| above eps, I / eps below.
        float gd[3];
        sh_direction_gradient(degree, d, s, gd);
        const float radial = d.length > kNormEps ? d.x * gd[0] + d.y * gd[1] + d.z * gd[2] : 0.0f;
        grad_means[3 * i] = (gd[0] - radial * d.x) / d.length;
        grad_means[3 * i + 1] = (gd[1] - radial * d.y) / d.length;
        grad_means[3 * i + 2] = (gd[2] - radial * d.z) / d.length;
    }
}

}  // namespace surgsplat

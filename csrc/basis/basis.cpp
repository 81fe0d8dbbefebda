// Gaussian-basis deformation channels; see basis.h for the arithmetic.
#include "basis/basis.h"

#include <algorithm>

#include "simd.h"

namespace surgsplat {
namespace {

constexpr int64_t kBlockValues = 4 * kMaxBasisFunctions;  // basis values of one block
static_assert(kBlockValues % kVecLanes == 0, "blocks are whole vectors");
constexpr float kLog2e = 1.4426950408889634f;

// Scratch of one block of Gaussians, [Gaussian, basis function] flattened.
struct BasisBlock {
    float value[kBlockValues];
    float z[kBlockValues];
    float inv_sigma[kBlockValues];
    float grad_value[kBlockValues];  // backward: d loss / d value
};

// The 16 values of `source` from j on, zeros past `end` (the block's last vector).
inline Vec16 load_lanes(const float* source, int64_t j, int64_t end) {
    if (j + kVecLanes <= end) return Vec16::load(source + j);
    float lanes[kVecLanes] = {};
    std::copy(source + j, source + end, lanes);
    return Vec16::load(lanes);
}

inline void store_lanes(const Vec16& x, float* target, int64_t j, int64_t end) {
    if (j + kVecLanes <= end) return x.store(target + j);
    float lanes[kVecLanes];
    x.store(lanes);
    std::copy(lanes, lanes + (end - j), target + j);
}

// value, z and inv_sigma of the `count` values centres[0, count), log_widths[0, count).
void evaluate_basis(const float* centres, const float* log_widths, int64_t count, float t,
                    BasisBlock& block) {
    for (int64_t j = 0; j < count; j += kVecLanes) {
        // exp(-log_width) = 2^(-log_width log2(e)), kept below pow2's limit of 2^127.
        Vec16 y = load_lanes(log_widths, j, count) * -kLog2e;
        y = select(y > 126.0f, Vec16::all(126.0f), y);
        const Vec16 inv_sigma = pow2(y);
        const Vec16 z = (t - load_lanes(centres, j, count)) * inv_sigma;
        pow2(z * z * (-0.5f * kLog2e)).store(block.value + j);
        z.store(block.z + j);
        inv_sigma.store(block.inv_sigma + j);
    }
}

// The blocks' size in Gaussians, and how many blocks cover n.
struct Blocking {
    int64_t gaussians, count;
};

Blocking blocking(int64_t n, int64_t basis) {
    const int64_t gaussians = kBlockValues / basis;
    return {gaussians, (n + gaussians - 1) / gaussians};
}

}  // namespace

void gaussian_basis_forward(const float* weights, const float* centres, const float* log_widths,
                            int64_t n, int64_t channels, int64_t basis, float t, float* out) {
    const Blocking blocks = blocking(n, basis);
#pragma omp parallel for schedule(static)
    for (int64_t k = 0; k < blocks.count; ++k) {
        const int64_t first = k * blocks.gaussians;
        const int64_t last = std::min(n, first + blocks.gaussians);
        BasisBlock block;
        evaluate_basis(centres + first * basis, log_widths + first * basis,
                       (last - first) * basis, t, block);
        for (int64_t i = first; i < last; ++i) {
            const float* value = block.value + (i - first) * basis;
            const float* w = weights + i * channels * basis;
            for (int64_t d = 0; d < channels; ++d) {
                float sum = 0.0f;
                for (int64_t b = 0; b < basis; ++b) sum += w[d * basis + b] * value[b];
                out[i * channels + d] = sum;
            }
        }
    }
}

void gaussian_basis_backward(const float* weights, const float* centres,
                             const float* log_widths, int64_t n, int64_t channels,
                             int64_t basis, float t, const float* grad_out,
                             float* grad_weights, float* grad_centres, float* grad_log_widths) {
    const Blocking blocks = blocking(n, basis);
#pragma omp parallel for schedule(static)
    for (int64_t k = 0; k < blocks.count; ++k) {
        const int64_t first = k * blocks.gaussians;
        const int64_t last = std::min(n, first + blocks.gaussians);
        const int64_t count = (last - first) * basis;
        BasisBlock block;
        evaluate_basis(centres + first * basis, log_widths + first * basis, count, t, block);
        const int64_t whole_vectors = (count + kVecLanes - 1) / kVecLanes * kVecLanes;
        std::fill(block.grad_value, block.grad_value + whole_vectors, 0.0f);
        for (int64_t i = first; i < last; ++i) {
            const float* value = block.value + (i - first) * basis;
            float* grad_value = block.grad_value + (i - first) * basis;
            const float* w = weights + i * channels * basis;
            float* gw = grad_weights + i * channels * basis;
            const float* g = grad_out + i * channels;
            for (int64_t d = 0; d < channels; ++d)
                for (int64_t b = 0; b < basis; ++b) {
                    gw[d * basis + b] = g[d] * value[b];
                    grad_value[b] += g[d] * w[d * basis + b];
                }
        }
        // d value / d z = -z value;  dz / d centre = -inv_sigma;  dz / d log_width = -z.
        for (int64_t j = 0; j < count; j += kVecLanes) {
            const Vec16 z = Vec16::load(block.z + j);
            const Vec16 minus_grad_z =
                Vec16::load(block.grad_value + j) * z * Vec16::load(block.value + j);
            store_lanes(minus_grad_z * Vec16::load(block.inv_sigma + j),
                        grad_centres + first * basis, j, count);
            store_lanes(minus_grad_z * z, grad_log_widths + first * basis, j, count);
        }
    }
}

}  // namespace surgsplat

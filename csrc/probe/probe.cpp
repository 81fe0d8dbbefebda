// The limit probe: a plain 16-lane compositing loop, one tile row per vector.
#include "probe/probe.h"

#include <vector>

#include "rasterize/common.h"

namespace surgsplat {
namespace {

// exp(x) for x <= 0, lane-wise, the usual way: x = n ln2 + r with |r| <= ln2 / 2, exp(r) by its
// degree-6 Taylor polynomial in Horner's scheme (relative error < 2e-7), 2^n built in the
// exponent bits. The kernels compute alpha as one power of two with a shorter dependency chain
// (simd.h, pow2); the probe stays the plain loop they are measured against.
SURGSPLAT_INLINE RowF plain_exp(RowF x) {
    x = select(x < -87.0f, row_of(-87.0f), x);
    const float round_magic = 12582912.0f;  // 1.5 * 2^23: adding it rounds to integer
    const RowF n = (x * 1.44269504088896341f + round_magic) - round_magic;
    const RowF r = x - n * 0.693145751953125f - n * 1.42860682030941723e-06f;
    RowF p = row_of(1.0f / 720.0f);
    p = p * r + 1.0f / 120.0f;
    p = p * r + 1.0f / 24.0f;
    p = p * r + 1.0f / 6.0f;
    p = p * r + 0.5f;
    p = p * r + 1.0f;
    p = p * r + 1.0f;
    return p * bits_as_float((to_int(n) + 127) << 23);
}

}  // namespace

double composite_probe(int64_t tiles, int64_t gaussians, int64_t channels) {
    // Gaussians of 2 to 5 pixels' radius centred in the tile, opacities 0.05 to 0.5, fixed
    // features: a deterministic stand-in for a tile list.
    std::vector<float> mx(gaussians), my(gaussians), a(gaussians), b(gaussians), c(gaussians);
    std::vector<float> opacity(gaussians), features(gaussians * channels);
    for (int64_t g = 0; g < gaussians; ++g) {
        const float u = static_cast<float>((g * 37) % 101) / 101.0f;
        const float v = static_cast<float>((g * 59) % 103) / 103.0f;
        mx[g] = 2.0f + 12.0f * u;
        my[g] = 2.0f + 12.0f * v;
        const float sigma = 1.0f + 1.5f * v;
        a[g] = 1.0f / (sigma * sigma);
        b[g] = 0.2f * (u - 0.5f) * a[g];
        c[g] = a[g] * (0.6f + 0.8f * u);
        opacity[g] = 0.05f + 0.45f * u;
        for (int64_t ch = 0; ch < channels; ++ch)
            features[g * channels + ch] = static_cast<float>((g + ch) % 7) / 7.0f;
    }
    const RowF lanes = lane_offsets();
    double total = 0.0;
#pragma omp parallel reduction(+ : total)
    {
        std::vector<RowF> accum(channels * kTile);
#pragma omp for schedule(static)
        for (int64_t tile = 0; tile < tiles; ++tile) {
            RowF trans[kTile];
            for (int row = 0; row < kTile; ++row) trans[row] = row_of(1.0f);
            for (RowF& value : accum) value = row_of(0.0f);
            // the tile index shifts the Gaussians by up to a pixel, so tiles differ
            const float shift = static_cast<float>(tile % 16) / 16.0f;
            for (int64_t g = 0; g < gaussians; ++g) {
                const RowF dx = lanes + (0.5f - mx[g] - shift);
                const RowF qa = a[g] * dx * dx, qb = 2.0f * b[g] * dx;
                const float* feature = features.data() + g * channels;
                for (int row = 0; row < kTile; ++row) {
                    const float dy = row + 0.5f - my[g];
                    const RowF q = qa + dy * (qb + c[g] * dy);
                    const RowF alpha = row_min(opacity[g] * plain_exp(-0.5f * q), kAlphaMax);
                    const RowF t_next = trans[row] * (1.0f - alpha);
                    // as in the kernels, a pixel stops below kTransmittanceMin (which also
                    // keeps denormal numbers out), but its lanes are still evaluated
                    const RowI use = (alpha >= kAlphaMin) & (q >= 0.0f) &
                                     (t_next >= kTransmittanceMin);
                    const RowF weight = select(use, alpha * trans[row], row_of(0.0f));
                    trans[row] = select(use, t_next, trans[row]);
                    for (int64_t ch = 0; ch < channels; ++ch)
                        accum[ch * kTile + row] += feature[ch] * weight;
                }
            }
            for (const RowF& value : accum) total += lane_sum(value);
        }
    }
    return total;
}

}  // namespace surgsplat

// Shared definitions of the tile rasterizer: tile geometry, the compositing constants and the
// per-pixel Gaussian evaluation that forward and backward must compute identically.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "simd.h"

namespace surgsplat {

constexpr int kTile = 16;                    // tile edge in pixels
constexpr int kTilePixels = kTile * kTile;   // pixels per tile
constexpr float kAlphaMax = 0.99f;           // alpha = min(0.99, o * exp(-q / 2))
constexpr float kAlphaMin = 1.0f / 255.0f;   // contributions below this are skipped
constexpr float kTransmittanceMin = 1e-4f;   // compositing stops below this transmittance

// One tile row: 16 float lanes (simd.h: one AVX-512 register, two AVX2 registers or four
// SSE / NEON registers, depending on the ISA variant being compiled).
static_assert(kTile == kVecLanes, "a tile row is one 16-lane vector");
typedef Vec16 RowF;
typedef Vec16i RowI;

SURGSPLAT_INLINE RowF row_of(float value) { return RowF::all(value); }
SURGSPLAT_INLINE RowI row_of(int32_t value) { return RowI::all(value); }

// The lane offsets 0, 1, ..., 15 of a tile row.
SURGSPLAT_INLINE RowF lane_offsets() {
    RowF lanes;
    for (int i = 0; i < kTile; ++i) lanes[i] = static_cast<float>(i);
    return lanes;
}

// A whole row (N = kRegs) or the registers of it that a Gaussian reaches (simd.h, part()).
template <int N>
using RowPart = Pack<float, N>;
template <int N>
using RowPartI = Pack<int32_t, N>;

template <int N>
SURGSPLAT_INLINE RowPart<N> row_min(RowPart<N> x, float bound) {
    return select(x > bound, RowPart<N>::all(bound), x);
}

// exp(x) for x <= 0, lane-wise: x = n ln2 + r with |r| <= ln2 / 2, exp(r) by its degree-6
// Taylor polynomial (relative error < 2e-7), 2^n built in the exponent bits.
template <int N>
SURGSPLAT_INLINE RowPart<N> row_exp(RowPart<N> x) {
    x = select(x < -87.0f, RowPart<N>::all(-87.0f), x);
    const float round_magic = 12582912.0f;  // 1.5 * 2^23: adding it rounds to integer
    const RowPart<N> n = (x * 1.44269504088896341f + round_magic) - round_magic;
    const RowPart<N> r = x - n * 0.693145751953125f - n * 1.42860682030941723e-06f;
    RowPart<N> p = RowPart<N>::all(1.0f / 720.0f);
    p = p * r + 1.0f / 120.0f;
    p = p * r + 1.0f / 24.0f;
    p = p * r + 1.0f / 6.0f;
    p = p * r + 0.5f;
    p = p * r + 1.0f;
    p = p * r + 1.0f;
    const RowPartI<N> exponent = (to_int(n) + 127) << 23;
    return p * bits_as_float(exponent);
}

// Screen-space Gaussian as the kernels read it.
struct Splat {
    float mx, my;     // mean in pixels
    float a, b, c;    // conic: q = a dx^2 + 2 b dx dy + c dy^2
    float opacity;
};

// Inclusive pixel box outside which a Gaussian's alpha is below kAlphaMin.
struct PixelBox {
    int32_t x0, y0, x1, y1;
};

// Whether row offset dy of a Gaussian reaches any pixel centre of the tile starting at px0:
// {q(dx, dy) <= q_max} is the interval of columns mx - b dy / a +- sqrt(disc) / a, with
// disc = dy^2 (b^2 - a c) + a q_max. A projected conic is positive definite (a > 0), so the
// interval is compared with the tile scaled by a: no division in this per-row test.
inline bool row_touches_tile(float mx, float a, float b, float c, float q_max, float dy,
                             int px0) {
    const float disc = dy * dy * (b * b - a * c) + a * q_max;
    if (!(disc > 0.0f)) return false;
    constexpr float kMargin = 0.01f;  // pixels, against rounding
    const float centre = a * mx - b * dy, half = std::sqrt(disc);
    return centre + half >= a * (px0 + 0.5f - kMargin) &&
           centre - half <= a * (px0 + kTile - 0.5f + kMargin);
}

// Tile lists: Gaussians overlapping tile t are ids[offsets[t] .. offsets[t+1]), nearest first.
struct TileBins {
    int tiles_x = 0, tiles_y = 0;
    std::vector<int32_t> offsets;   // [tiles + 1]
    std::vector<int32_t> ids;       // [total overlaps]
    std::vector<PixelBox> boxes;    // [N], x1 < x0 when the Gaussian is not drawn
    std::vector<float> q_max;       // [N] alpha >= kAlphaMin where q <= q_max = 2 ln(o / kAlphaMin)
};

// One Gaussian as seen from one tile: what both compositing passes evaluate row by row.
struct SplatInTile {
    float mx, my, a, b, c, opacity, q_max;
    RowF dx, qa, qb;   // per lane: dx, a dx^2 and 2 b dx, so that q = qa + dy (qb + c dy)
    int row0, row1;    // the tile rows its alpha box covers
    int lane0, lane1;  // the tile columns (lanes) its alpha box covers
    bool spills;       // its box spills over the tile's sides: some rows may miss the tile

    SplatInTile(const float* means2d, const float* conics, const float* opacities,
                const TileBins& bins, int32_t g, int px0, int py0, RowF lanes)
        : mx(means2d[2 * g]), my(means2d[2 * g + 1]), a(conics[3 * g]), b(conics[3 * g + 1]),
          c(conics[3 * g + 2]), opacity(opacities[g]), q_max(bins.q_max[g]) {
        const PixelBox& box = bins.boxes[g];
        dx = lanes + (px0 + 0.5f - mx);
        qa = a * dx * dx;
        qb = 2.0f * b * dx;
        row0 = box.y0 - py0 > 0 ? box.y0 - py0 : 0;
        row1 = box.y1 - py0 < kTile - 1 ? box.y1 - py0 : kTile - 1;
        lane0 = box.x0 - px0 > 0 ? box.x0 - px0 : 0;
        lane1 = box.x1 - px0 < kTile - 1 ? box.x1 - px0 : kTile - 1;
        spills = box.x0 < px0 || box.x1 >= px0 + kTile;
    }

    // Whether tile row offset dy can reach alpha >= kAlphaMin inside the tile.
    bool reaches(float dy, int px0) const {
        return !spills || row_touches_tile(mx, a, b, c, q_max, dy, px0);
    }
    // q and alpha in the registers R0 .. R0 + N - 1 of tile row offset dy.
    template <int R0, int N>
    SURGSPLAT_INLINE RowPart<N> q(float dy) const {
        return part<R0, N>(qa) + dy * (part<R0, N>(qb) + c * dy);
    }
    template <int N>
    SURGSPLAT_INLINE RowPart<N> alpha(RowPart<N> q) const {
        return row_min(opacity * row_exp(-0.5f * q), kAlphaMax);
    }

    // f(R0, N) (std::integral_constant) for the registers holding lanes lane0 .. lane1: narrow
    // Gaussians skip the registers of the row their box does not reach, where alpha is below
    // kAlphaMin anyway (without AVX-512: half of a row's work for boxes within 8 columns).
    template <class F>
    SURGSPLAT_INLINE void with_reached_registers(F&& f) const {
        with_registers(lane0, lane1, f);
    }
};

// Gaussians ahead in a tile list whose data is requested from memory before it is composited:
// tile lists visit Gaussians in depth order, so their data is scattered over arrays larger than
// L2, and the per-Gaussian work is too long for the CPU to run ahead to the next loads itself.
constexpr int kPrefetchAhead = 4;

// Requests the cache lines that compositing Gaussian g reads.
inline void prefetch_splat(const float* means2d, const float* conics, const float* opacities,
                           const float* features, int64_t channels, const TileBins& bins,
                           int32_t g) {
    __builtin_prefetch(means2d + 2 * g);
    __builtin_prefetch(conics + 3 * g);
    __builtin_prefetch(opacities + g);
    __builtin_prefetch(features + g * channels);
    __builtin_prefetch(bins.boxes.data() + g);
    __builtin_prefetch(bins.q_max.data() + g);
}

TileBins bin_gaussians(const float* means2d, const float* conics, const float* opacities,
                       const float* depths, const int32_t* radii, int64_t n, int width,
                       int height);

void rasterize_forward(const float* means2d, const float* conics, const float* opacities,
                       const float* features, int64_t channels, const TileBins& bins,
                       int width, int height, float* image, float* transmittance,
                       int32_t* last_entry);

void rasterize_backward(const float* means2d, const float* conics, const float* opacities,
                        const float* features, int64_t n, int64_t channels,
                        const TileBins& bins, int width, int height,
                        const float* transmittance, const int32_t* last_entry,
                        const float* grad_image, const float* grad_alpha,
                        float* grad_means2d, float* grad_conics, float* grad_opacities,
                        float* grad_features, float* abs_grad_means2d);

}  // namespace surgsplat

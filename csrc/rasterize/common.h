// Shared definitions of the tile rasterizer: tile geometry, the compositing constants and the
// per-pixel Gaussian evaluation that forward and backward must compute identically.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "simd.h"

namespace surgsplat {

constexpr int kTile = 16;                    // tile edge in pixels
constexpr float kAlphaMax = 0.99f;           // alpha = min(0.99, o * exp(-q / 2))
constexpr float kAlphaMin = 1.0f / 255.0f;   // contributions below this are skipped
constexpr float kTransmittanceMin = 1e-4f;   // compositing stops below this transmittance
constexpr float kLog2e = 1.44269504088896341f;

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

// A whole row or band (below), or the registers of it that a Gaussian reaches (simd.h, part()).
template <int N>
using RowPart = Pack<float, N>;
template <int N>
using RowPartI = Pack<int32_t, N>;

template <int N>
SURGSPLAT_INLINE RowPart<N> row_min(RowPart<N> x, float bound) {
    return select(x > bound, RowPart<N>::all(bound), x);
}

// Tile bands: the compositing passes hold a tile as kBands bands of kBandRows pixel rows. A
// band is kBandRegs registers; register j covers the columns j kBandCols .. (j + 1) kBandCols - 1
// of the band's rows, lane l of it column l % kBandCols of those and row l / kBandCols of the
// band. With 8 or 4 lanes (AVX2, SSE, NEON) a band is one tile row; with 16 (AVX-512) it is two
// rows, and a register 8 columns x 2 rows. A Gaussian composites only the registers of its
// columns (SplatInTile), so on AVX-512 one within 8 columns of a tile takes one register per
// two rows instead of one per row (the surface scene of bench_render: 21 % fewer registers).
constexpr int kBandCols = kRegLanes < 8 ? kRegLanes : 8;
constexpr int kBandRows = kRegLanes / kBandCols;
constexpr int kBandRegs = kTile / kBandCols;
constexpr int kBands = kTile / kBandRows;
constexpr int kBandLanes = kBandRegs * kRegLanes;  // pixels of a band
typedef Pack<float, kBandRegs> BandF;
typedef Pack<int32_t, kBandRegs> BandI;

// The column in the tile and the row in the band of band lane i.
constexpr int band_column(int i) { return i / kRegLanes * kBandCols + i % kBandCols; }
constexpr int band_row(int i) { return i % kRegLanes / kBandCols; }

// Per band lane, its column in the tile (columns) or its row in the band (rows).
SURGSPLAT_INLINE BandF band_lanes(bool columns) {
    BandF lanes;
    for (int i = 0; i < kBandLanes; ++i)
        lanes[i] = static_cast<float>(columns ? band_column(i) : band_row(i));
    return lanes;
}

// The band of an [height, width] image (one value per pixel) whose first pixel is (px0, y0), of
// which the first `columns` columns and `rows` rows are in the image; the others read `outside`.
template <class T>
SURGSPLAT_INLINE Pack<T, kBandRegs> load_band(const T* image, int width, int px0, int y0,
                                              int columns, int rows, T outside) {
    const T* first = image + static_cast<int64_t>(y0) * width + px0;
    if (kBandRows == 1 && columns == kTile && rows == 1) return Pack<T, kBandRegs>::load(first);
    Pack<T, kBandRegs> band = Pack<T, kBandRegs>::all(outside);
    for (int i = 0; i < kBandLanes; ++i)
        if (band_column(i) < columns && band_row(i) < rows)
            band[i] = first[static_cast<int64_t>(band_row(i)) * width + band_column(i)];
    return band;
}

// Inclusive pixel box outside which a Gaussian's alpha is below kAlphaMin.
struct PixelBox {
    int32_t x0, y0, x1, y1;
};

// A Gaussian's reach {a u^2 + 2 b u v + c v^2 <= q_max} (u = x - mx, v = y - my), described
// for narrow_to_tile_rows: its half width in u, the u of its top point (where v is highest,
// v_top = sqrt(a q_max / det)) and 1 / c. Computed once per Gaussian in binning, it saves three
// square roots and five divisions per (Gaussian, tile). Binning draws only det > 0, a > 0,
// q_max > 0.
struct Reach {
    float half_width, u_top, inv_c;

    static Reach of(float a, float b, float c, float q_max) {
        const float det = a * c - b * b;
        return {std::sqrt(c * q_max / det), -b * std::sqrt(a * q_max / det) / a, 1.0f / c};
    }
};

// Narrows the tile rows [row0, row1] to those where a Gaussian can reach alpha >= kAlphaMin at
// a pixel centre of the columns of the tile starting at px0 (tile rows start at py0); false
// when it reaches none. Cut to the strip of the tile's columns the reach (an ellipse, above)
// stays convex, so the rows it reaches are one run, from the lowest to the highest v on the
// cut. The ellipse's upper boundary v(u) = (-b u + sqrt(c q_max - det u^2)) / c is concave with
// its maximum at the top point: its highest v on the cut is at the u of the cut nearest that
// point; the lowest v likewise, at the bottom point. Computed once per Gaussian and tile, this
// replaces a test (a square root and a branch) per row. Rounding margins keep the run a
// superset: the lanes' own alpha test decides what contributes.
inline bool narrow_to_tile_rows(float mx, float my, float a, float b, float c, float q_max,
                                const Reach& reach, int px0, int py0, int& row0, int& row1) {
    constexpr float kMargin = 0.01f;  // pixels, against rounding
    const float u0 = std::max(px0 + 0.5f - kMargin - mx, -reach.half_width);
    const float u1 = std::min(px0 + kTile - 0.5f + kMargin - mx, reach.half_width);
    if (!(u0 <= u1)) return false;
    const float det = a * c - b * b, c_q_max = c * q_max;
    const auto boundary_root = [&](float u) {
        return std::sqrt(std::max(c_q_max - det * u * u, 0.0f));
    };
    const float u_high = std::min(std::max(reach.u_top, u0), u1);
    const float u_low = std::min(std::max(-reach.u_top, u0), u1);
    const float v_high = (-b * u_high + boundary_root(u_high)) * reach.inv_c + kMargin;
    const float v_low = (-b * u_low - boundary_root(u_low)) * reach.inv_c - kMargin;
    // row r holds the pixel centres v = py0 + r + 0.5 - my; the bounds are clamped to a
    // tile's rows before conversion
    const float first = std::ceil(v_low + my - py0 - 0.5f);
    const float last = std::floor(v_high + my - py0 - 0.5f);
    row0 = std::max(row0, static_cast<int>(std::min(std::max(first, -1.0f), float(kTile))));
    row1 = std::min(row1, static_cast<int>(std::min(std::max(last, -1.0f), float(kTile))));
    return row0 <= row1;
}

// One drawn Gaussian as the compositing passes read it: 64 bytes, aligned to a cache line so
// that reading one takes one line.
struct alignas(64) SplatRecord {
    float mx, my;     // mean in pixels
    float a, b, c;    // conic: q = a dx^2 + 2 b dx dy + c dy^2
    float opacity;
    float q_max;      // alpha >= kAlphaMin where q <= q_max = 2 ln(opacity / kAlphaMin)
    float log2_opacity;
    PixelBox box;     // inclusive pixel box of alpha >= kAlphaMin
    int32_t id;       // the Gaussian's index in the inputs
    Reach reach;
};
static_assert(sizeof(SplatRecord) == 64, "a splat record fills one cache line");

// The part of one tile a Gaussian reaches: tile rows row0 .. row1 and columns (lanes) lane0 ..
// lane1. Binning computes it once per (Gaussian, tile) and keeps it beside the tile lists: in the
// compositing passes its square roots and branches sat at the head of every (Gaussian, tile)
// step, and the row loop's bounds waited for them.
struct TileSpan {
    uint8_t row0, row1, lane0, lane1;
};

// The span of the tile whose top left pixel is (px0, py0) where `splat` can reach alpha >=
// kAlphaMin; false when it reaches no pixel centre of the tile (a tile its box touches beside
// a tilted ellipse).
inline bool span_in_tile(const SplatRecord& splat, int px0, int py0, TileSpan& span) {
    const PixelBox& box = splat.box;
    int row0 = std::max(box.y0 - py0, 0), row1 = std::min(box.y1 - py0, kTile - 1);
    const int lane0 = std::max(box.x0 - px0, 0), lane1 = std::min(box.x1 - px0, kTile - 1);
    // a box spilling over the tile's sides may miss the tile in some of its rows
    const bool spills = box.x0 < px0 || box.x1 >= px0 + kTile;
    if (spills && !narrow_to_tile_rows(splat.mx, splat.my, splat.a, splat.b, splat.c,
                                       splat.q_max, splat.reach, px0, py0, row0, row1))
        return false;
    span = TileSpan{static_cast<uint8_t>(row0), static_cast<uint8_t>(row1),
                    static_cast<uint8_t>(lane0), static_cast<uint8_t>(lane1)};
    return true;
}

// Tile lists: tile t composites the drawn Gaussians of ranks[offsets[t] .. offsets[t+1]),
// nearest first, each over its spans[] entry (the tiles a Gaussian's box touches but its alpha
// >= kAlphaMin ellipse misses are left out). A rank is a position in the depth order, and
// indexes copies of the drawn Gaussians' data made in that order (splats, features): every tile
// list is increasing in rank, so the passes read their Gaussians' data in memory order instead
// of gathering it from the inputs' arbitrary order (measured: 8-15% of the forward and backward
// time).
struct TileBins {
    int tiles_x = 0, tiles_y = 0;
    int64_t num_gaussians = 0;          // N, Gaussians in the inputs
    int64_t channels = 0;               // C, feature channels
    std::vector<int32_t> offsets;       // [tiles + 1]
    std::vector<int32_t> ranks;         // [total overlaps]
    std::vector<TileSpan> spans;        // [total overlaps], the part of the tile each reaches
    int64_t box_overlaps = 0;           // (tile, Gaussian) pairs of the alpha boxes, >= overlaps
    std::vector<SplatRecord> splats;    // [drawn], nearest first
    std::vector<float> features;        // [drawn, C], nearest first
    std::vector<float> background;      // [C], seen through the remaining transmittance
};

// One Gaussian as seen from one tile: what both compositing passes evaluate band by band.
// alpha = min(kAlphaMax, o exp(-q / 2)) is computed as 2^y with y = log2(o) - q log2(e) / 2,
// the opacity and the scale folded into per-lane terms: y = ya + dy (yb + yc dy). Binning draws
// only positive definite conics, so q >= 0 (up to rounding) without a test.
struct SplatInTile {
    float mx, my, a, b, c, opacity, yc;
    // per band lane: dx, log2(o) - log2(e) a dx^2 / 2, -log2(e) b dx, and dy in band 0
    BandF dx, ya, yb, dy0;
    int band0, band1;  // the bands holding the tile rows it reaches
    int reg0, reg1;    // the band registers holding the tile columns its alpha box covers

    // columns and rows: band_lanes(true) and band_lanes(false)
    SplatInTile(const SplatRecord& splat, TileSpan span, int px0, int py0, const BandF& columns,
                const BandF& rows)
        : mx(splat.mx), my(splat.my), a(splat.a), b(splat.b), c(splat.c),
          opacity(splat.opacity), yc(-0.5f * kLog2e * splat.c), band0(span.row0 / kBandRows),
          band1(span.row1 / kBandRows), reg0(span.lane0 / kBandCols),
          reg1(span.lane1 / kBandCols) {
        dx = columns + (px0 + 0.5f - mx);
        dy0 = rows + (py0 + 0.5f - my);
        ya = (-0.5f * kLog2e * a) * dx * dx + splat.log2_opacity;
        yb = (-kLog2e * b) * dx;
    }
    // dy in the registers R0 .. R0 + N - 1 of `band`.
    template <int R0, int N>
    SURGSPLAT_INLINE RowPart<N> dy(int band) const {
        return part<R0, N>(dy0) + static_cast<float>(band * kBandRows);
    }
    // alpha in the registers R0 .. R0 + N - 1 of a band, at their dy.
    template <int R0, int N>
    SURGSPLAT_INLINE RowPart<N> alpha(const RowPart<N>& dy) const {
        const RowPart<N> y = part<R0, N>(ya) + dy * (part<R0, N>(yb) + yc * dy);
        return row_min(pow2(y), kAlphaMax);
    }

    // f(R0, N) (std::integral_constant) for the band registers holding lanes lane0 .. lane1:
    // narrow Gaussians skip the registers their box does not reach, where alpha is below
    // kAlphaMin anyway.
    template <class F>
    SURGSPLAT_INLINE void with_reached_registers(F&& f) const {
        with_registers<kBandRegs>(reg0, reg1, f);
    }
};

// Gaussians ahead in a tile list whose data is requested from memory before it is composited:
// tile lists visit Gaussians in depth order, so their data is scattered over arrays larger than
// L2, and the per-Gaussian work is too long for the CPU to run ahead to the next loads itself.
constexpr int kPrefetchAhead = 4;

// Requests the cache lines that compositing the Gaussian of `rank` reads.
inline void prefetch_splat(const TileBins& bins, int32_t rank) {
    prefetch(bins.splats.data() + rank);
    prefetch(bins.features.data() + rank * bins.channels);
}

// Requests the cache lines of one tile's pixels in an image of `values` per pixel (interleaved,
// [height, width, values]): the 16 rows of a tile are far apart in memory, a pattern the
// hardware prefetchers do not follow; reading (backward) or writing (forward) a tile's pixels on
// demand stalled each pass for 5-10 % of its time (perf, real clip).
template <class T>
inline void prefetch_tile_pixels(const T* image, int64_t values, int width, int height,
                                 int tile_x, int tile_y) {
    const int px0 = tile_x * kTile, py0 = tile_y * kTile;
    const int64_t columns = std::min(kTile, width - px0) * values;
    for (int y = py0; y < std::min(py0 + kTile, height); ++y) {
        const char* first =
            reinterpret_cast<const char*>(image + (int64_t(y) * width + px0) * values);
        const char* end = first + columns * sizeof(T);
        for (const char* line = first; line < end; line += 64) prefetch(line);
        prefetch(end - 1);
    }
}

// Bins the Gaussians: means2d [N, 2], conics [N, 3], opacities [N], features [N, C], depths [N]
// (sort key), radii [N] (0 = not drawn).
TileBins bin_gaussians(const float* means2d, const float* conics, const float* opacities,
                       const float* features, int64_t channels, const float* depths,
                       const int32_t* radii, int64_t n, int width, int height);

// image [H, W, C] (the Gaussians composited over bins.background), transmittance [H, W] and
// last_entry [H, W] (one past the list entry of each pixel's last contributor) of the binned
// Gaussians.
void rasterize_forward(const TileBins& bins, int width, int height, float* image,
                       float* transmittance, int32_t* last_entry);

// Gradients [N, ...] of the inputs' means2d, conics, opacities and features (added to
// grad_features), and the per-Gaussian sum of |dL/dmean2d|, from the forward's outputs. With
// gradient weights (both non-null), the gradient a Gaussian with weighted_members [N] != 0 gets
// from pixel p is scaled by pixel_weights [H, W] at p.
void rasterize_backward(const TileBins& bins, int width, int height,
                        const float* transmittance, const int32_t* last_entry,
                        const float* grad_image, const float* grad_alpha,
                        float* grad_means2d, float* grad_conics, float* grad_opacities,
                        float* grad_features, float* abs_grad_means2d,
                        const float* pixel_weights, const uint8_t* weighted_members);

}  // namespace surgsplat

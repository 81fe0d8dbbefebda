// Backward compositing: per tile, Gaussians back to front, recovering each pixel's transmittance
// by a reciprocal (T_before = T_after / (1 - alpha), simd.h) and what lies behind it
// incrementally. Gradients are summed per thread, then reduced, so no atomics are needed.
//
// With w_i = alpha_i T_i, the image is C = sum_i w_i f_i and the alpha map A = sum_i w_i, so
//   dL/df_i     = w_i dL/dC
//   dL/dalpha_i = T_i [ (f_i - behind_i) . dL/dC + (1 - behind_alpha_i) dL/dA ]
//               = T_i [ (f_i . dL/dC + dL/dA) - (behind_i . dL/dC + behind_alpha_i dL/dA) ]
// where behind_i, behind_alpha_i are what the Gaussians after i and the background composite
// to, seen from just behind i (behind the last contributor: the background and alpha 0). Both
// brackets are per-pixel scalars: the second, the pixel's `behind` below, obeys the compositing
// recursion itself (behind_{i-1} = behind_i + alpha_i (first - behind_i)), as dL/dC and dL/dA
// are constant per pixel. So a pixel carries two values back to front, its transmittance and
// this dot product, instead of C + 2 (the colour and alpha behind it).
//
// Gradient weights (pixel_weights, weighted_members) scale the member Gaussians' gradients per
// pixel: at pixel p, a member's own terms (w_i dL/dC and alpha_i dL/dalpha_i) are multiplied by
// pixel_weights[p] (0 drops them, 1 keeps them whole), while the recursion, and so every other
// Gaussian's gradient, is unchanged.
#include <algorithm>
#include <memory>

#include <omp.h>

#include "common.h"

namespace surgsplat {
namespace {

// Per-Gaussian gradient slots in a thread's buffer.
enum Slot : int { kMx, kMy, kA, kB, kC, kOpacity, kAbsX, kAbsY, kFeatures };
static_assert(kFeatures == 8, "the per-Gaussian sums are reduced as one group of eight");

// Ranks ahead whose gradient outputs the reduction requests before writing them.
constexpr int64_t kScatterAhead = 16;

}  // namespace

void rasterize_backward(const TileBins& bins, int width, int height,
                        const float* transmittance, const int32_t* last_entry,
                        const float* grad_image, const float* grad_alpha,
                        float* grad_means2d, float* grad_conics, float* grad_opacities,
                        float* grad_features, float* abs_grad_means2d,
                        const float* pixel_weights, const uint8_t* weighted_members) {
    const int tiles = bins.tiles_x * bins.tiles_y;
    const int64_t n = bins.num_gaussians, channels = bins.channels;
    const int64_t drawn = static_cast<int64_t>(bins.splats.size());
    const int64_t stride = kFeatures + channels;
    const int threads = omp_get_max_threads();
    const BandF columns = band_lanes(true), rows = band_lanes(false);
    // per thread, one gradient slot per drawn Gaussian, in depth order (by rank); each thread
    // zeroes its own slots (in parallel, and on the thread's side of the memory)
    const size_t slots = static_cast<size_t>(drawn) * stride;
    std::unique_ptr<float[]> partial(new float[threads * slots]);
#pragma omp parallel
    {
        float* mine = partial.get() + static_cast<size_t>(omp_get_thread_num()) * slots;
        std::fill(mine, mine + slots, 0.0f);
        std::vector<BandF> grad_in(channels * kBands);  // [channel][band]
        std::vector<BandF> grad_f(channels);
        BandF trans[kBands], behind[kBands], grad_a[kBands];
        BandI last[kBands];
        BandF member_weight[kBands];  // per lane, the weight of a member's gradient there
        int32_t band_last[kBands];  // per band, the largest last entry: later Gaussians skip it
        // interleaved static schedule: the same tiles go to the same thread on every call, so the
        // per-thread sums, and the gradients, are reproducible
#pragma omp for schedule(static, 1)
        for (int tile = 0; tile < tiles; ++tile) {
            const int px0 = (tile % bins.tiles_x) * kTile, py0 = (tile / bins.tiles_x) * kTile;
            const int32_t start = bins.offsets[tile], end = bins.offsets[tile + 1];
            const int next = tile + omp_get_num_threads();  // this thread's next tile
            if (next < tiles) {
                const int next_x = next % bins.tiles_x, next_y = next / bins.tiles_x;
                prefetch_tile_pixels(transmittance, 1, width, height, next_x, next_y);
                prefetch_tile_pixels(last_entry, 1, width, height, next_x, next_y);
                prefetch_tile_pixels(grad_alpha, 1, width, height, next_x, next_y);
                if (pixel_weights != nullptr)
                    prefetch_tile_pixels(pixel_weights, 1, width, height, next_x, next_y);
                prefetch_tile_pixels(grad_image, channels, width, height, next_x, next_y);
            }
            // the tile's pixels; those outside the image composite nothing and get no gradient
            const int in_columns = std::min(kTile, width - px0);
            for (int band = 0; band < kBands; ++band) {
                const int y0 = py0 + band * kBandRows;
                const int in_rows = std::max(0, std::min(kBandRows, height - y0));
                trans[band] = load_band(transmittance, width, px0, y0, in_columns, in_rows, 1.0f);
                last[band] = load_band(last_entry, width, px0, y0, in_columns, in_rows, start);
                grad_a[band] = load_band(grad_alpha, width, px0, y0, in_columns, in_rows, 0.0f);
                member_weight[band] =
                    pixel_weights == nullptr
                        ? BandF::all(1.0f)
                        : load_band(pixel_weights, width, px0, y0, in_columns, in_rows, 1.0f);
                behind[band] = BandF::all(0.0f);
                for (int64_t ch = 0; ch < channels; ++ch) {
                    BandF& grad = grad_in[ch * kBands + band];
                    grad = BandF::all(0.0f);
                    for (int i = 0; i < kBandLanes; ++i)
                        if (band_column(i) < in_columns && band_row(i) < in_rows)
                            grad[i] = grad_image[((static_cast<int64_t>(y0) + band_row(i)) * width +
                                                  px0 + band_column(i)) * channels + ch];
                    behind[band] += bins.background[ch] * grad;
                }
                band_last[band] = start;
                for (int i = 0; i < kBandLanes; ++i)
                    band_last[band] = std::max(band_last[band], last[band][i]);
            }
            // Gaussians behind every pixel's last contributor (where compositing stopped) have
            // no gradient: the walk back to front starts at the tile's last contributor.
            const int32_t tile_last = *std::max_element(band_last, band_last + kBands);
            for (int32_t k = tile_last - 1; k >= start; --k) {
                const int32_t rank = bins.ranks[k];
                if (k - kPrefetchAhead >= start) {
                    const int32_t ahead = bins.ranks[k - kPrefetchAhead];
                    prefetch_splat(bins, ahead);
                    prefetch(mine + ahead * stride);  // both lines a slot may span
                    prefetch(mine + (ahead + 1) * stride - 1);
                }
                const SplatInTile s(bins.splats[rank], bins.spans[k], px0, py0, columns, rows);
                const float a = s.a, b = s.b, c = s.c, inv_opacity = 1.0f / s.opacity;
                const float* feature = bins.features.data() + rank * channels;
                const bool weighted =
                    weighted_members != nullptr && weighted_members[bins.splats[rank].id];
                s.with_reached_registers([&](auto first_register, auto registers) {
                    constexpr int R0 = decltype(first_register)::value;
                    constexpr int N = decltype(registers)::value;
                    const RowPart<N> dx = part<R0, N>(s.dx);
                    const RowPart<N> a_dx = a * dx, b_dx = b * dx;
                    // Per lane sums over the bands of ad = alpha dL/dalpha where alpha is free, of
                    // ad dy and of ad dy^2: with dL/dq = -ad / 2 and q = a dx^2 + 2 b dx dy +
                    // c dy^2 (dx constant in a lane, which keeps its column in every band), they
                    // give the mean, conic and opacity gradients after the bands (below), three
                    // accumulations per band instead of a dozen operations.
                    RowPart<N> sum_ad{}, sum_ad_dy{}, sum_ad_dy2{}, abs_x{}, abs_y{};
                    for (BandF& sum : grad_f) set_part<R0, N>(sum, RowPart<N>{});
                    bool touched = false;
                    for (int band = s.band0; band <= s.band1; ++band) {
                        if (k >= band_last[band]) continue;
                        const RowPart<N> dy = s.template dy<R0, N>(band);
                        touched = true;
                        const RowPart<N> raw = s.template alpha<R0, N>(dy);
                        const RowPartI<N> in = (k < part<R0, N>(last[band])) & (raw >= kAlphaMin);
                        const RowPart<N> alpha = select(in, raw, RowPart<N>{});
                        // lanes without this Gaussian keep their transmittance exactly
                        const RowPart<N> t_after = part<R0, N>(trans[band]);
                        const RowPart<N> t_before =
                            select(in, t_after * reciprocal(1.0f - alpha), t_after);
                        const RowPart<N> weight = alpha * t_before;
                        // the weight of this Gaussian's own gradient at each lane's pixel
                        const RowPart<N> learns =
                            weighted ? part<R0, N>(member_weight[band]) : RowPart<N>::all(1.0f);
                        const RowPart<N> own_weight = weight * learns;
                        // first = f . dL/dC + dL/dA: this Gaussian's own term of dL/dalpha
                        RowPart<N> first = part<R0, N>(grad_a[band]);
                        for (int64_t ch = 0; ch < channels; ++ch) {
                            const RowPart<N> grad = part<R0, N>(grad_in[ch * kBands + band]);
                            set_part<R0, N>(grad_f[ch],
                                            part<R0, N>(grad_f[ch]) + own_weight * grad);
                            first += feature[ch] * grad;
                        }
                        const RowPart<N> behind_dot = part<R0, N>(behind[band]);
                        const RowPart<N> difference = first - behind_dot;
                        const RowPart<N> d_alpha = t_before * difference;
                        set_part<R0, N>(behind[band], behind_dot + alpha * difference);
                        set_part<R0, N>(trans[band], t_before);
                        // alpha = o G with G = exp(-q/2), unless clamped at kAlphaMax (then no
                        // gradient)
                        const RowPart<N> ad = select(in & (alpha < kAlphaMax),
                                                     alpha * d_alpha * learns, RowPart<N>{});
                        sum_ad += ad;
                        sum_ad_dy += ad * dy;
                        sum_ad_dy2 += ad * (dy * dy);
                        // this pixel's dL/dmean2d = ad (a dx + b dy, b dx + c dy)
                        abs_x += abs(ad * (a_dx + b * dy));
                        abs_y += abs(ad * (b_dx + c * dy));
                    }
                    if (!touched) return;
                    // summed over the pixels: dL/dmx = ad (a dx + b dy), dL/da = -ad dx^2 / 2,
                    // dL/db = -ad dx dy, dL/dc = -ad dy^2 / 2, dL/do = ad / o (slot order)
                    const RowPart<N> terms[8] = {
                        a_dx * sum_ad + b * sum_ad_dy, b_dx * sum_ad + c * sum_ad_dy,
                        -0.5f * dx * dx * sum_ad, -dx * sum_ad_dy, -0.5f * sum_ad_dy2,
                        inv_opacity * sum_ad, abs_x, abs_y};
                    float sums[8];
                    lane_sums8(terms, sums);
                    float* slot = mine + rank * stride;
                    for (int i = 0; i < kFeatures; ++i) slot[i] += sums[i];
                    for (int64_t ch0 = 0; ch0 < channels; ch0 += 8) {
                        const int64_t count = std::min<int64_t>(8, channels - ch0);
                        RowPart<N> features[8];
                        for (int i = 0; i < 8; ++i)
                            features[i] = i < count ? part<R0, N>(grad_f[ch0 + i]) : RowPart<N>{};
                        lane_sums8(features, sums);
                        for (int64_t i = 0; i < count; ++i) slot[kFeatures + ch0 + i] += sums[i];
                    }
                });
            }
        }
        // Gaussians that are not drawn have no gradient (grad_features comes zeroed)
#pragma omp for schedule(static)
        for (int64_t g = 0; g < n; ++g) {
            grad_means2d[2 * g] = grad_means2d[2 * g + 1] = 0.0f;
            grad_conics[3 * g] = grad_conics[3 * g + 1] = grad_conics[3 * g + 2] = 0.0f;
            grad_opacities[g] = 0.0f;
            abs_grad_means2d[2 * g] = abs_grad_means2d[2 * g + 1] = 0.0f;
        }
#pragma omp for schedule(static)
        for (int64_t rank = 0; rank < drawn; ++rank) {
            if (rank + kScatterAhead < drawn) {  // the outputs are written in the inputs' order
                const int64_t ahead = bins.splats[rank + kScatterAhead].id;
                prefetch(grad_features + ahead * channels);
                prefetch(grad_means2d + 2 * ahead);
                prefetch(grad_conics + 3 * ahead);
                prefetch(grad_opacities + ahead);
                prefetch(abs_grad_means2d + 2 * ahead);
            }
            const int64_t g = bins.splats[rank].id;
            float sums[kFeatures] = {};
            for (int th = 0; th < threads; ++th) {
                const float* s = partial.get() + th * slots + rank * stride;
                for (int i = 0; i < kFeatures; ++i) sums[i] += s[i];
                for (int64_t ch = 0; ch < channels; ++ch)
                    grad_features[g * channels + ch] += s[kFeatures + ch];
            }
            grad_means2d[2 * g] = sums[kMx];
            grad_means2d[2 * g + 1] = sums[kMy];
            grad_conics[3 * g] = sums[kA];
            grad_conics[3 * g + 1] = sums[kB];
            grad_conics[3 * g + 2] = sums[kC];
            grad_opacities[g] = sums[kOpacity];
            abs_grad_means2d[2 * g] = sums[kAbsX];
            abs_grad_means2d[2 * g + 1] = sums[kAbsY];
        }
    }
}

}  // namespace surgsplat

// Forward compositing: parallel over tiles; inside a tile, Gaussians front to back, each over
// the bands (common.h) holding the rows it reaches, and in each band only the registers holding
// its columns.
#include <algorithm>

#include "common.h"

namespace surgsplat {

void rasterize_forward(const TileBins& bins, int width, int height, float* image,
                       float* transmittance, int32_t* last_entry) {
    const int tiles = bins.tiles_x * bins.tiles_y;
    const int64_t channels = bins.channels;
    const BandF columns = band_lanes(true), rows = band_lanes(false);
#pragma omp parallel
    {
        std::vector<BandF> accum(channels * kBands);  // [channel][band]
        BandF trans[kBands];
        BandI live[kBands];   // all ones while the pixel still composites
        BandI last[kBands];   // one past the list entry of the last contributor
        bool band_live[kBands];
#pragma omp for schedule(dynamic, 1)
        for (int tile = 0; tile < tiles; ++tile) {
            const int32_t start = bins.offsets[tile], end = bins.offsets[tile + 1];
            // the tile's outputs are written at its end: their lines arrive while it composites
            const int tile_x = tile % bins.tiles_x, tile_y = tile / bins.tiles_x;
            prefetch_tile_pixels(image, channels, width, height, tile_x, tile_y);
            prefetch_tile_pixels(transmittance, 1, width, height, tile_x, tile_y);
            prefetch_tile_pixels(last_entry, 1, width, height, tile_x, tile_y);
            const int px0 = tile_x * kTile, py0 = tile_y * kTile;
            std::fill(accum.begin(), accum.end(), BandF::all(0.0f));
            const BandI in_columns =
                (columns + static_cast<float>(px0)) < static_cast<float>(width);
            for (int band = 0; band < kBands; ++band) {
                const float y0 = static_cast<float>(py0 + band * kBandRows);
                trans[band] = BandF::all(1.0f);
                live[band] = in_columns & ((rows + y0) < static_cast<float>(height));
                last[band] = BandI::all(start);
                band_live[band] = any_lane(live[band]);
            }
            for (int32_t k = start; k < end; ++k) {
                const int32_t rank = bins.ranks[k];
                if (k + kPrefetchAhead < end) prefetch_splat(bins, bins.ranks[k + kPrefetchAhead]);
                const SplatInTile s(bins.splats[rank], bins.spans[k], px0, py0, columns, rows);
                const float* feature = bins.features.data() + rank * channels;
                bool any_live = false;
                s.with_reached_registers([&](auto first_register, auto registers) {
                    constexpr int R0 = decltype(first_register)::value;
                    constexpr int N = decltype(registers)::value;
                    for (int band = s.band0; band <= s.band1; ++band) {
                        if (!band_live[band]) continue;
                        const RowPart<N> alpha =
                            s.template alpha<R0, N>(s.template dy<R0, N>(band));
                        const RowPart<N> t = part<R0, N>(trans[band]);
                        const RowPartI<N> in = part<R0, N>(live[band]) & (alpha >= kAlphaMin);
                        const RowPart<N> t_next = t * (1.0f - alpha);
                        const RowPartI<N> stop = in & (t_next < kTransmittanceMin);
                        const RowPartI<N> use = in & ~stop;
                        const RowPart<N> weight = select(use, alpha * t, RowPart<N>{});
                        set_part<R0, N>(trans[band], select(use, t_next, t));
                        set_part<R0, N>(last[band], select(use, RowPartI<N>::all(k + 1),
                                                           part<R0, N>(last[band])));
                        if (any_lane(stop)) {
                            set_part<R0, N>(live[band], part<R0, N>(live[band]) & ~stop);
                            band_live[band] = any_lane(live[band]);
                        }
                        any_live = true;
                        for (int64_t ch = 0; ch < channels; ++ch) {
                            BandF& sum = accum[ch * kBands + band];
                            set_part<R0, N>(sum, part<R0, N>(sum) + feature[ch] * weight);
                        }
                    }
                });
                if (!any_live &&
                    std::none_of(band_live, band_live + kBands, [](bool b) { return b; }))
                    break;
            }
            for (int band = 0; band < kBands; ++band) {
                for (int i = 0; i < kBandLanes; ++i) {
                    const int x = px0 + band_column(i), y = py0 + band * kBandRows + band_row(i);
                    if (x >= width || y >= height) continue;
                    const int64_t pixel = static_cast<int64_t>(y) * width + x;
                    const float t = trans[band][i];
                    for (int64_t ch = 0; ch < channels; ++ch)
                        image[pixel * channels + ch] =
                            accum[ch * kBands + band][i] + t * bins.background[ch];
                    transmittance[pixel] = t;
                    last_entry[pixel] = last[band][i];
                }
            }
        }
    }
}

}  // namespace surgsplat

// Forward compositing: parallel over tiles; inside a tile, Gaussians front to back, each over
// the tile rows it reaches, one 16-lane vector per row (only the registers of it that
// the box reaches).
#include <algorithm>

#include "common.h"

namespace surgsplat {

void rasterize_forward(const TileBins& bins, int width, int height, float* image,
                       float* transmittance, int32_t* last_entry) {
    const int tiles = bins.tiles_x * bins.tiles_y;
    const int64_t channels = bins.channels;
    const RowF lanes = lane_offsets();
#pragma omp parallel
    {
        std::vector<RowF> accum(channels * kTile);  // [channel][row]
        RowF trans[kTile];
        RowI live[kTile];   // all ones while the pixel still composites
        RowI last[kTile];   // one past the list entry of the last contributor
        bool row_live[kTile];
#pragma omp for schedule(dynamic, 1)
        for (int tile = 0; tile < tiles; ++tile) {
            const int32_t start = bins.offsets[tile], end = bins.offsets[tile + 1];
            // the tile's outputs are written at its end: their lines arrive while it composites
            const int tile_x = tile % bins.tiles_x, tile_y = tile / bins.tiles_x;
            prefetch_tile_pixels(image, channels, width, height, tile_x, tile_y);
            prefetch_tile_pixels(transmittance, 1, width, height, tile_x, tile_y);
            prefetch_tile_pixels(last_entry, 1, width, height, tile_x, tile_y);
            const int px0 = tile_x * kTile, py0 = tile_y * kTile;
            std::fill(accum.begin(), accum.end(), row_of(0.0f));
            const RowI in_image = (lanes + static_cast<float>(px0)) < static_cast<float>(width);
            for (int row = 0; row < kTile; ++row) {
                trans[row] = row_of(1.0f);
                live[row] = py0 + row < height ? in_image : row_of(0);
                last[row] = row_of(start);
                row_live[row] = any_lane(live[row]);
            }
            for (int32_t k = start; k < end; ++k) {
                const int32_t rank = bins.ranks[k];
                if (k + kPrefetchAhead < end) prefetch_splat(bins, bins.ranks[k + kPrefetchAhead]);
                const SplatInTile s(bins.splats[rank], bins.spans[k], px0, lanes);
                const float* feature = bins.features.data() + rank * channels;
                bool any_live = false;
                s.with_reached_registers([&](auto first_register, auto registers) {
                    constexpr int R0 = decltype(first_register)::value;
                    constexpr int N = decltype(registers)::value;
                    for (int row = s.row0; row <= s.row1; ++row) {
                        if (!row_live[row]) continue;
                        const RowPart<N> alpha = s.template alpha<R0, N>(py0 + row + 0.5f - s.my);
                        const RowPart<N> t = part<R0, N>(trans[row]);
                        const RowPartI<N> in = part<R0, N>(live[row]) & (alpha >= kAlphaMin);
                        const RowPart<N> t_next = t * (1.0f - alpha);
                        const RowPartI<N> stop = in & (t_next < kTransmittanceMin);
                        const RowPartI<N> use = in & ~stop;
                        const RowPart<N> weight = select(use, alpha * t, RowPart<N>{});
                        set_part<R0, N>(trans[row], select(use, t_next, t));
                        set_part<R0, N>(last[row], select(use, RowPartI<N>::all(k + 1),
                                                          part<R0, N>(last[row])));
                        if (any_lane(stop)) {
                            set_part<R0, N>(live[row], part<R0, N>(live[row]) & ~stop);
                            row_live[row] = any_lane(live[row]);
                        }
                        any_live = true;
                        for (int64_t ch = 0; ch < channels; ++ch) {
                            RowF& sum = accum[ch * kTile + row];
                            set_part<R0, N>(sum, part<R0, N>(sum) + feature[ch] * weight);
                        }
                    }
                });
                if (!any_live && std::none_of(row_live, row_live + kTile, [](bool r) { return r; }))
                    break;
            }
            for (int row = 0; row < kTile && py0 + row < height; ++row) {
                for (int col = 0; col < kTile && px0 + col < width; ++col) {
                    const int64_t pixel = static_cast<int64_t>(py0 + row) * width + px0 + col;
                    const float t = trans[row][col];
                    for (int64_t ch = 0; ch < channels; ++ch)
                        image[pixel * channels + ch] =
                            accum[ch * kTile + row][col] + t * bins.background[ch];
                    transmittance[pixel] = t;
                    last_entry[pixel] = last[row][col];
                }
            }
        }
    }
}

}  // namespace surgsplat

// Forward compositing: parallel over tiles; inside a tile the loop runs Gaussian by Gaussian
// (front to back) over whole 16-pixel rows, so the per-pixel work vectorises.
#include <algorithm>

#include "common.h"

namespace surgsplat {

void rasterize_forward(const float* means2d, const float* conics, const float* opacities,
                       const float* features, int64_t channels, const TileBins& bins,
                       int width, int height, float* image, float* transmittance,
                       int32_t* last_entry) {
    const int tiles = bins.tiles_x * bins.tiles_y;
#pragma omp parallel
    {
        std::vector<float> accum(channels * kTilePixels);
        alignas(64) float trans[kTilePixels];
        alignas(64) float live[kTilePixels];
        alignas(64) int32_t last[kTilePixels];
        alignas(64) float weight[kTile];
        int row_live[kTile];  // live pixels per row: rows with none are skipped
#pragma omp for schedule(dynamic, 1)
        for (int tile = 0; tile < tiles; ++tile) {
            const int px0 = (tile % bins.tiles_x) * kTile, py0 = (tile / bins.tiles_x) * kTile;
            const int32_t start = bins.offsets[tile], end = bins.offsets[tile + 1];
            std::fill(accum.begin(), accum.end(), 0.0f);
            int remaining = 0;
            std::fill(row_live, row_live + kTile, 0);
            for (int p = 0; p < kTilePixels; ++p) {
                const bool inside = px0 + p % kTile < width && py0 + p / kTile < height;
                trans[p] = 1.0f;
                live[p] = inside ? 1.0f : 0.0f;
                last[p] = start;
                remaining += inside;
                row_live[p / kTile] += inside;
            }
            for (int32_t k = start; k < end && remaining > 0; ++k) {
                const int32_t g = bins.ids[k];
                const PixelBox& box = bins.boxes[g];
                const float mx = means2d[2 * g], my = means2d[2 * g + 1];
                const float a = conics[3 * g], b = conics[3 * g + 1], c = conics[3 * g + 2];
                const float opacity = opacities[g];
                const int col0 = std::max(box.x0 - px0, 0), col1 = std::min(box.x1 - px0, kTile - 1);
                const int row0 = std::max(box.y0 - py0, 0), row1 = std::min(box.y1 - py0, kTile - 1);
                const float* feature = features + g * channels;
                for (int row = row0; row <= row1; ++row) {
                    if (row_live[row] == 0) continue;
                    const float dy = py0 + row + 0.5f - my;
                    float* t_row = trans + row * kTile;
                    float* live_row = live + row * kTile;
                    int32_t* last_row = last + row * kTile;
                    int stopped = 0;
#pragma omp simd reduction(+ : stopped)
                    for (int col = 0; col < kTile; ++col) {
                        const float dx = px0 + col + 0.5f - mx;
                        const float q = a * dx * dx + 2.0f * b * dx * dy + c * dy * dy;
                        const float alpha = std::min(kAlphaMax, opacity * fast_exp(-0.5f * q));
                        const bool in = col >= col0 && col <= col1 && live_row[col] > 0.0f &&
                                        alpha >= kAlphaMin && q >= 0.0f;
                        const float t_next = t_row[col] * (1.0f - alpha);
                        const bool stop = in && t_next < kTransmittanceMin;
                        const bool use = in && !stop;
                        weight[col] = use ? alpha * t_row[col] : 0.0f;
                        t_row[col] = use ? t_next : t_row[col];
                        last_row[col] = use ? k + 1 : last_row[col];
                        live_row[col] = stop ? 0.0f : live_row[col];
                        stopped += stop ? 1 : 0;
                    }
                    for (int64_t ch = 0; ch < channels; ++ch) {
                        const float f = feature[ch];
                        float* acc_row = accum.data() + ch * kTilePixels + row * kTile;
#pragma omp simd
                        for (int col = 0; col < kTile; ++col) acc_row[col] += f * weight[col];
                    }
                    remaining -= stopped;
                    row_live[row] -= stopped;
                }
            }
            for (int p = 0; p < kTilePixels; ++p) {
                const int x = px0 + p % kTile, y = py0 + p / kTile;
                if (x >= width || y >= height) continue;
                const int64_t pixel = static_cast<int64_t>(y) * width + x;
                for (int64_t ch = 0; ch < channels; ++ch)
                    image[pixel * channels + ch] = accum[ch * kTilePixels + p];
                transmittance[pixel] = trans[p];
                last_entry[pixel] = last[p];
            }
        }
    }
}

}  // namespace surgsplat

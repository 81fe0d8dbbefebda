// Backward compositing: per tile, Gaussians back to front, recovering each pixel's transmittance
// by division (T_before = T_after / (1 - alpha)) and the colour behind it incrementally.
// Gradients are summed per thread, then reduced, so no atomics are needed.
//
// With w_i = alpha_i T_i, the image is C = sum_i w_i f_i and the alpha map A = sum_i w_i, so
//   dL/df_i     = w_i dL/dC
//   dL/dalpha_i = T_i [ (f_i - behind_i) . dL/dC + (1 - behind_alpha_i) dL/dA ]
// where behind_i is what the Gaussians after i composite to, seen from just behind i.
#include <algorithm>

#include <omp.h>

#include "common.h"

namespace surgsplat {
namespace {

// Per-Gaussian gradient slots in a thread's buffer.
enum Slot : int { kMx, kMy, kA, kB, kC, kOpacity, kAbsX, kAbsY, kFeatures };

}  // namespace

void rasterize_backward(const float* means2d, const float* conics, const float* opacities,
                        const float* features, int64_t n, int64_t channels,
                        const TileBins& bins, int width, int height,
                        const float* transmittance, const int32_t* last_entry,
                        const float* grad_image, const float* grad_alpha,
                        float* grad_means2d, float* grad_conics, float* grad_opacities,
                        float* grad_features, float* abs_grad_means2d) {
    const int tiles = bins.tiles_x * bins.tiles_y;
    const int64_t stride = kFeatures + channels;
    const int threads = omp_get_max_threads();
    std::vector<float> partial(static_cast<size_t>(threads) * n * stride, 0.0f);
#pragma omp parallel
    {
        float* mine = partial.data() + static_cast<size_t>(omp_get_thread_num()) * n * stride;
        std::vector<float> behind(channels * kTilePixels), grad_in(channels * kTilePixels);
        alignas(64) float trans[kTilePixels];
        alignas(64) float behind_alpha[kTilePixels];
        alignas(64) float grad_a[kTilePixels];
        alignas(64) int32_t last[kTilePixels];
        int32_t row_last[kTile];  // per row, the largest last_entry: later Gaussians skip it
        alignas(64) float use[kTile], alpha_row[kTile], t_before[kTile], dalpha[kTile];
#pragma omp for schedule(dynamic, 1)
        for (int tile = 0; tile < tiles; ++tile) {
            const int px0 = (tile % bins.tiles_x) * kTile, py0 = (tile / bins.tiles_x) * kTile;
            const int32_t start = bins.offsets[tile], end = bins.offsets[tile + 1];
            std::fill(behind.begin(), behind.end(), 0.0f);
            std::fill(row_last, row_last + kTile, start);
            for (int p = 0; p < kTilePixels; ++p) {
                const int x = px0 + p % kTile, y = py0 + p / kTile;
                const bool inside = x < width && y < height;
                const int64_t pixel = static_cast<int64_t>(y) * width + x;
                trans[p] = inside ? transmittance[pixel] : 1.0f;
                last[p] = inside ? last_entry[pixel] : start;
                row_last[p / kTile] = std::max(row_last[p / kTile], last[p]);
                grad_a[p] = inside ? grad_alpha[pixel] : 0.0f;
                behind_alpha[p] = 0.0f;
                for (int64_t ch = 0; ch < channels; ++ch)
                    grad_in[ch * kTilePixels + p] = inside ? grad_image[pixel * channels + ch] : 0.0f;
            }
            for (int32_t k = end - 1; k >= start; --k) {
                const int32_t g = bins.ids[k];
                const PixelBox& box = bins.boxes[g];
                const float mx = means2d[2 * g], my = means2d[2 * g + 1];
                const float a = conics[3 * g], b = conics[3 * g + 1], c = conics[3 * g + 2];
                const float opacity = opacities[g];
                const int col0 = std::max(box.x0 - px0, 0), col1 = std::min(box.x1 - px0, kTile - 1);
                const int row0 = std::max(box.y0 - py0, 0), row1 = std::min(box.y1 - py0, kTile - 1);
                const float* feature = features + g * channels;
                float* slot = mine + g * stride;
                float g_mx = 0, g_my = 0, g_a = 0, g_b = 0, g_c = 0, g_o = 0, abs_x = 0, abs_y = 0;
                for (int row = row0; row <= row1; ++row) {
                    if (k >= row_last[row]) continue;
                    const float dy = py0 + row + 0.5f - my;
                    float* t_row = trans + row * kTile;
                    const int32_t* last_row = last + row * kTile;
#pragma omp simd
                    for (int col = 0; col < kTile; ++col) {
                        const float dx = px0 + col + 0.5f - mx;
                        const float q = a * dx * dx + 2.0f * b * dx * dy + c * dy * dy;
                        const float alpha = std::min(kAlphaMax, opacity * fast_exp(-0.5f * q));
                        const bool in = col >= col0 && col <= col1 && k < last_row[col] &&
                                        alpha >= kAlphaMin && q >= 0.0f;
                        use[col] = in ? 1.0f : 0.0f;
                        alpha_row[col] = in ? alpha : 0.0f;
                        t_before[col] = in ? t_row[col] / (1.0f - alpha) : t_row[col];
                        dalpha[col] = 0.0f;
                    }
                    for (int64_t ch = 0; ch < channels; ++ch) {
                        const float f = feature[ch];
                        float* behind_row = behind.data() + ch * kTilePixels + row * kTile;
                        const float* grad_row = grad_in.data() + ch * kTilePixels + row * kTile;
                        float g_f = 0.0f;
#pragma omp simd reduction(+ : g_f)
                        for (int col = 0; col < kTile; ++col) {
                            const float w = alpha_row[col] * t_before[col];
                            g_f += w * grad_row[col];
                            dalpha[col] += use[col] * (f - behind_row[col]) * grad_row[col];
                            behind_row[col] += alpha_row[col] * (f - behind_row[col]);
                        }
                        slot[kFeatures + ch] += g_f;
                    }
                    float* ba_row = behind_alpha + row * kTile;
                    const float* ga_row = grad_a + row * kTile;
#pragma omp simd reduction(+ : g_mx, g_my, g_a, g_b, g_c, g_o, abs_x, abs_y)
                    for (int col = 0; col < kTile; ++col) {
                        const float dx = px0 + col + 0.5f - mx;
                        const float d_alpha = use[col] * t_before[col] *
                                              (dalpha[col] + (1.0f - ba_row[col]) * ga_row[col]);
                        ba_row[col] += alpha_row[col] * (1.0f - ba_row[col]);
                        t_row[col] = t_before[col];
                        // alpha = o G with G = exp(-q/2), unless clamped at kAlphaMax
                        const float gauss = alpha_row[col] / opacity;
                        const bool clamped = opacity * gauss >= kAlphaMax;
                        const float d_o = clamped ? 0.0f : gauss * d_alpha;
                        const float d_q = clamped ? 0.0f : -0.5f * alpha_row[col] * d_alpha;
                        const float d_mx = -d_q * (2.0f * a * dx + 2.0f * b * dy);
                        const float d_my = -d_q * (2.0f * b * dx + 2.0f * c * dy);
                        g_o += d_o;
                        g_a += d_q * dx * dx;
                        g_b += d_q * 2.0f * dx * dy;
                        g_c += d_q * dy * dy;
                        g_mx += d_mx;
                        g_my += d_my;
                        abs_x += std::fabs(d_mx);
                        abs_y += std::fabs(d_my);
                    }
                }
                slot[kMx] += g_mx;
                slot[kMy] += g_my;
                slot[kA] += g_a;
                slot[kB] += g_b;
                slot[kC] += g_c;
                slot[kOpacity] += g_o;
                slot[kAbsX] += abs_x;
                slot[kAbsY] += abs_y;
            }
        }
#pragma omp for schedule(static)
        for (int64_t g = 0; g < n; ++g) {
            float sums[kFeatures] = {};
            for (int th = 0; th < threads; ++th) {
                const float* s = partial.data() + (static_cast<size_t>(th) * n + g) * stride;
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

// Separable blur with a symmetric 1D kernel and zero padding ('same' size), streamed row by row
// between a caller's row producer and consumer; the plain blur of float32 planes; and SSIM with
// its backward built on the stream.
//
// With a symmetric kernel and zero padding the blur matrix B is symmetric (B[i][j] = t[j - i] =
// t[i - j] along each axis, no boundary rows folded back), so the adjoint B^T, i.e. the backward
// pass of out = B planes, is the same blur applied to the upstream gradient.
#pragma once

#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <vector>

#include "simd.h"

namespace surgsplat {

namespace blur_detail {

// 16 float lanes (simd.h): one AVX-512 register, two AVX2 or four SSE / NEON registers.
// Accumulators are explicit vectors so they stay in registers.
typedef Vec16 Lanes;
constexpr int64_t kLanes = kVecLanes;
constexpr int64_t kChunk = 2 * kLanes;  // columns per accumulator block

inline int64_t round_up(int64_t n) { return (n + kChunk - 1) / kChunk * kChunk; }

SURGSPLAT_INLINE Lanes load(const float* p) { return Lanes::load(p); }

SURGSPLAT_INLINE void store(float* p, const Lanes& v) { v.store(p); }

// dst[x] = sum_k taps[k] row[x + k - radius] for x in [0, round_up(width)): `row` has `radius`
// zeros before it and zeros from `width` to round_up(width) + radius, so the loop has no
// boundary cases; columns past `width` are scratch.
inline void blur_row(const float* row, int64_t width, const float* taps, int radius,
                     float* __restrict dst) {
    for (int64_t x0 = 0; x0 < width; x0 += kChunk) {
        const float* c = row + x0;
        Lanes lo = taps[radius] * load(c), hi = taps[radius] * load(c + kLanes);
        for (int k = 1; k <= radius; ++k) {
            const float w = taps[radius + k];
            lo += w * (load(c - k) + load(c + k));
            hi += w * (load(c + kLanes - k) + load(c + kLanes + k));
        }
        store(dst + x0, lo);
        store(dst + x0 + kLanes, hi);
    }
}

// dst[x] = sum_k taps[k] rows[k][x] for x in [0, round_up(width)); rows and dst hold
// round_up(width) columns.
inline void blur_column(const float* const* rows, int64_t width, const float* taps, int radius,
                        float* __restrict dst) {
    for (int64_t x0 = 0; x0 < width; x0 += kChunk) {
        const float* c = rows[radius] + x0;
        Lanes lo = taps[radius] * load(c), hi = taps[radius] * load(c + kLanes);
        for (int k = 1; k <= radius; ++k) {
            const float w = taps[radius + k];
            const float* up = rows[radius - k] + x0;
            const float* down = rows[radius + k] + x0;
            lo += w * (load(up) + load(down));
            hi += w * (load(up + kLanes) + load(down + kLanes));
        }
        store(dst + x0, lo);
        store(dst + x0 + kLanes, hi);
    }
}

}  // namespace blur_detail

// Blurs `groups` groups of `planes` planes [height, width] that exist only row by row: each
// thread calls make_worker() once, and its worker's
//   load(group, y, float* const* rows)          writes row y of the group's planes into
//                                               rows[0 .. planes), `width` floats each;
//   store(group, y, const float* const* rows)   takes row y of the blurred planes.
// Every row is loaded once per task, tasks being blocks of rows of one group (in parallel), so
// a task also loads the `radius` rows around its block. The kernel `taps` has 2 radius + 1
// symmetric weights; rows outside the planes count as zero.
template <class MakeWorker>
void blur_streamed(int64_t groups, int planes, int64_t height, int64_t width, const float* taps,
                   int radius, MakeWorker make_worker) {
    using namespace blur_detail;
    if (groups <= 0 || height <= 0 || width <= 0) return;
    // Row blocks per group: at least two tasks per thread, and if possible a task count that the
    // threads share evenly; fewer blocks mean fewer halo rows loaded twice.
    const int64_t threads = omp_get_max_threads();
    int64_t blocks = std::min<int64_t>(height, (2 * threads + groups - 1) / groups);
    while ((groups * blocks) % threads != 0 && blocks < height) ++blocks;
    const int64_t block_rows = (height + blocks - 1) / blocks;
    blocks = (height + block_rows - 1) / block_rows;
    const int64_t ring_rows = 2 * radius + 1, stride = round_up(width);
#pragma omp parallel
    {
        auto worker = make_worker();
        // per plane: [radius zeros | loaded row | zeros up to stride + radius]
        std::vector<float> loaded(planes * (stride + 2 * radius), 0.0f);
        std::vector<float> ring(planes * ring_rows * stride);  // row y at slot y % ring_rows
        std::vector<float> blurred(planes * stride);
        std::vector<float*> load_rows(planes), store_rows(planes);
        const std::vector<float> zeros(stride, 0.0f);  // the rows outside the planes
        std::vector<const float*> window(ring_rows);  // rows y - radius .. y + radius
        for (int p = 0; p < planes; ++p) {
            load_rows[p] = loaded.data() + p * (stride + 2 * radius) + radius;
            store_rows[p] = blurred.data() + p * stride;
        }
#pragma omp for schedule(dynamic, 1)
        for (int64_t task = 0; task < groups * blocks; ++task) {
            const int64_t group = task / blocks, row0 = (task % blocks) * block_rows;
            const int64_t row1 = std::min(height, row0 + block_rows);
            int64_t next = std::max<int64_t>(0, row0 - radius);  // next row to load
            for (int64_t y = row0; y < row1; ++y) {
                for (; next <= std::min(height - 1, y + radius); ++next) {
                    worker.load(group, next, load_rows.data());
                    for (int p = 0; p < planes; ++p)
                        blur_row(load_rows[p], width, taps, radius,
                                 ring.data() + (p * ring_rows + next % ring_rows) * stride);
                }
                for (int p = 0; p < planes; ++p) {
                    const float* slots = ring.data() + p * ring_rows * stride;
                    for (int64_t k = -radius; k <= radius; ++k)
                        window[radius + k] = y + k < 0 || y + k >= height
                            ? zeros.data() : slots + ((y + k) % ring_rows) * stride;
                    blur_column(window.data(), width, taps, radius, store_rows[p]);
                }
                worker.store(group, y, store_rows.data());
            }
        }
    }
}

// out[p] = the blur of planes[p] for each of the `count` planes [height, width] (C-contiguous).
void blur_planes(const float* planes, int64_t count, int64_t height, int64_t width,
                 const float* taps, int radius, float* out);

// Per-pixel, per-channel SSIM S of images pred, gt [height, width, channels] with the window
// `taps` and the constants c1, c2. Writes the blurred moments [4, channels, height, width]
// (E[x], E[y], E[x^2] + E[y^2], E[xy]; the backward reads them) and, unless null, the map S
// [height, width, channels]. Returns the score: the sum of weights[pixel] * S over pixels and
// channels (weights [height, width]; all ones when null). With image_mask [height, width] (not
// null), both images are multiplied by it before filtering: with a 0/1 mask, the pixels outside
// it read as 0 in both (the masked D-SSIM loss), without a masked copy of either image.
double ssim_forward(const float* pred, const float* gt, int64_t height, int64_t width,
                    int64_t channels, const float* taps, int radius, float c1, float c2,
                    const float* weights, const float* image_mask, float* moments, float* map);

// The gradient of a loss L with respect to the map S: grad_map [height, width, channels] when
// not null, else grad_score * weights[pixel] (the backward of the score; weights null: ones).
struct SsimUpstream {
    const float* grad_map;
    const float* weights;
    float grad_score;
};

// Gradients of L with respect to pred and gt [height, width, channels] (either not computed
// when its pointer is null), given the moments written by ssim_forward with the same
// image_mask.
void ssim_backward(const float* pred, const float* gt, const float* moments, int64_t height,
                   int64_t width, int64_t channels, const float* taps, int radius, float c1,
                   float c2, const SsimUpstream& upstream, const float* image_mask,
                   float* grad_pred, float* grad_gt);

}  // namespace surgsplat

// HexPlane backward. With p_k the six sampled feature vectors of a scale and g the upstream
// gradient of their product, plane k receives g * prod_{j != k} p_j scattered to its four cell
// nodes with the bilinear weights, and each space coordinate the same vector dotted with the
// derivative of p_k along it. One pass per slab (scale, 16 features) over all points; plane
// gradients are summed in per-thread buffers (points split statically, buffers added in thread
// order) and coordinate gradients slab after slab, so results repeat bit for bit for a given
// thread count.
#include <algorithm>

#include <omp.h>

#include "common.h"

namespace surgsplat {
namespace {

// Gradients of one slab (scale s, chunk c) for the points of a block, added to the thread's
// plane-gradient buffer `mine` and to grad_coords.
void slab_backward(const Slabs& slabs, int64_t s, int64_t c, const Lanes* values, Lanes* mine,
                   const BlockCells& cells, int64_t first, int64_t points, int64_t n,
                   const float* grad_out, float* grad_coords) {
    const int64_t features = slabs.features, width = slabs.scales() * features;
    const int64_t count = std::min<int64_t>(features - c * kLanes, kLanes);
    const Lanes* slab[kPlanesPerScale];
    Lanes* target[kPlanesPerScale];
    int64_t row[kPlanesPerScale];
    for (int k = 0; k < kPlanesPerScale; ++k) {
        const int64_t offset = slabs.slab(s * kPlanesPerScale + k, c);
        slab[k] = values + offset;
        target[k] = mine + offset;
        row[k] = slabs.nodes[s][kWidthAxis[k]];
    }
    for (int l = 0; l < points; ++l) {
        const int64_t i = first + l;
        const float* upstream_row = grad_out + i * width + s * features + c * kLanes;
        if (i + kPrefetchPoints < n) prefetch(upstream_row + kPrefetchPoints * width);
        Lanes value[kPlanesPerScale];
        for (int k = 0; k < kPlanesPerScale; ++k) value[k] = sample(slab[k], row[k], cells, k, l);
        // upstream[k] = g p_0 ... p_{k-1}; `after` runs over p_{k+1} ... p_5
        Lanes upstream[kPlanesPerScale];
        upstream[0] = load_lanes(upstream_row, count);
        for (int k = 1; k < kPlanesPerScale; ++k) upstream[k] = upstream[k - 1] * value[k - 1];
        Lanes after = Lanes{} + 1.0f;
        Lanes axis_grad[kSpaceAxes] = {};
#pragma GCC unroll 6  // constant axes: axis_grad stays in registers
        for (int k = kPlanesPerScale - 1; k >= 0; --k) {
            const Lanes grad = upstream[k] * after;
            after *= value[k];
            const int64_t node = cells.node[k][l], r = row[k];
            const Lanes* q = slab[k] + node;
            const Lanes q00 = q[0], q01 = q[1], q10 = q[r], q11 = q[r + 1];
            axis_grad[kWidthAxis[k]] +=
                grad * ((q01 - q00) * cells.dx0[k][l] + (q11 - q10) * cells.dx1[k][l]);
            if (kHeightAxis[k] < kSpaceAxes)
                axis_grad[kHeightAxis[k]] +=
                    grad * ((q10 - q00) * cells.dy0[k][l] + (q11 - q01) * cells.dy1[k][l]);
            Lanes* t = target[k] + node;
            t[0] += grad * cells.w00[k][l];
            t[1] += grad * cells.w01[k][l];
            t[r] += grad * cells.w10[k][l];
            t[r + 1] += grad * cells.w11[k][l];
        }
        for (int a = 0; a < kSpaceAxes; ++a)
            grad_coords[i * kSpaceAxes + a] += lane_sum(axis_grad[a]);
    }
}

// Sums the thread buffers [threads][slabs.size()] in thread order into the planes' gradients
// ([features, height, width] each), one plane row per iteration.
void reduce_threads(const Slabs& slabs, const Lanes* partial, int threads,
                    const std::vector<float*>& grad_planes) {
#pragma omp for schedule(static)
    for (int64_t r = 0; r < slabs.rows.back(); ++r) {
        size_t p = 0;
        while (slabs.rows[p + 1] <= r) ++p;
        const PlaneView& view = slabs.planes[p];
        const int64_t y = r - slabs.rows[p], area = view.height * view.width;
        for (int64_t c = 0; c < slabs.chunks; ++c) {
            const int64_t first = slabs.slab(static_cast<int64_t>(p), c) + y * view.width;
            const int64_t count = std::min<int64_t>(slabs.features - c * kLanes, kLanes);
            for (int64_t x = 0; x < view.width; ++x) {
                Lanes sum = partial[first + x];
                for (int t = 1; t < threads; ++t) sum += partial[t * slabs.size() + first + x];
                float* target = grad_planes[p] + (c * kLanes) * area + y * view.width + x;
                for (int64_t f = 0; f < count; ++f) target[f * area] = sum[f];
            }
        }
    }
}

}  // namespace

void hexplane_backward(const float* coords, int64_t n, const Slabs& slabs, const float* grad_out,
                       float* grad_coords, const std::vector<float*>& grad_planes) {
    const int64_t size = slabs.size(), blocks = (n + kLanes - 1) / kLanes;
    const int threads = omp_get_max_threads();
    std::unique_ptr<Lanes[]> values = slabs.allocate(1);
    slabs.gather(values.get());
    std::unique_ptr<Lanes[]> partial = slabs.allocate(threads);  // [threads][size]
#pragma omp parallel
    {
#pragma omp for schedule(static)
        for (int t = 0; t < threads; ++t)
            std::fill(partial.get() + t * size, partial.get() + (t + 1) * size, Lanes{});
        Lanes* mine = partial.get() + static_cast<int64_t>(omp_get_thread_num()) * size;
        // the same static split of the blocks in every pass: a thread adds to its own points'
        // coordinate gradients only, so the passes need no barrier between them
#pragma omp for schedule(static)
        for (int64_t i = 0; i < n * kSpaceAxes; ++i) grad_coords[i] = 0.0f;
        BlockCells cells;
        for (int64_t s = 0; s < slabs.scales(); ++s) {
            for (int64_t c = 0; c < slabs.chunks; ++c) {
#pragma omp for schedule(static) nowait
                for (int64_t b = 0; b < blocks; ++b) {
                    const int64_t first = b * kLanes, points = std::min<int64_t>(n - first, kLanes);
                    block_cells(slabs, s, coords, first, points, cells);
                    slab_backward(slabs, s, c, values.get(), mine, cells, first, points, n,
                                  grad_out, grad_coords);
                }
            }
        }
#pragma omp barrier
        reduce_threads(slabs, partial.get(), threads, grad_planes);
    }
}

}  // namespace surgsplat

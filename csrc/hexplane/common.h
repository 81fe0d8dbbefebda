// Shared definitions of the HexPlane sampler: the six planes of a scale, their slab layout, and
// the bilinear cells that forward and backward must compute identically
// (torch.nn.functional.grid_sample with align_corners=True and border padding).
//
// Both kernels work slab by slab: one scale and 16 features at a time, over all points, so that
// the plane values (and, backward, their gradients) read by a pass mostly fit in L2. The cells of
// 16 points are computed together, one point per vector lane.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "simd.h"

namespace surgsplat {

constexpr int kPlanesPerScale = 6;
// Coordinate axes (x=0, y=1, z=2, t=3) along the width and the height of the planes of one
// scale, in the order xy, xz, yz, xt, yt, zt.
constexpr int kWidthAxis[kPlanesPerScale] = {0, 0, 1, 0, 1, 2};
constexpr int kHeightAxis[kPlanesPerScale] = {1, 2, 2, 3, 3, 3};
constexpr int kAxes = 4;         // coordinates per point: x, y, z, t
constexpr int kSpaceAxes = 3;    // coordinates that receive gradients: x, y, z

// 16 lanes (simd.h): one AVX-512 register, two AVX2 or four SSE / NEON registers.
constexpr int kLanes = kVecLanes;
typedef Vec16 Lanes;
typedef Vec16i LanesI;

// A feature plane as the caller holds it: [features, height, width], C-contiguous.
struct PlaneView {
    const float* data;
    int64_t height, width;
};

// The planes as the kernels read them, in a buffer of Lanes: features 16c .. 16c + 15 of plane p
// (zero beyond `features`) form the slab [height, width] starting at slab(p, c).
// Within a scale every axis has one node count (std::invalid_argument otherwise): x is the width
// of xy, xz and xt, y the height of xy and the width of yz and yt, z the height of xz and yz and
// the width of zt, t the height of xt, yt and zt.
struct Slabs {
    int64_t features, chunks;
    std::vector<PlaneView> planes;
    std::vector<int64_t> start;                     // [planes + 1], in Lanes
    std::vector<int64_t> rows;                      // [planes + 1], prefix sums of the heights
    std::vector<std::array<int64_t, kAxes>> nodes;  // [scales], node count along x, y, z, t

    Slabs(std::vector<PlaneView> views, int64_t features);
    int64_t scales() const { return static_cast<int64_t>(nodes.size()); }
    int64_t size() const { return start.back(); }
    int64_t slab(int64_t plane, int64_t chunk) const {
        return start[plane] + chunk * planes[plane].height * planes[plane].width;
    }
    // An uninitialised buffer of size() Lanes per copy.
    std::unique_ptr<Lanes[]> allocate(int64_t copies) const;
    // The planes' values, zero padded, into `buffer` (one copy).
    void gather(Lanes* buffer) const;
};

// How far ahead (in points) the kernels prefetch their rows of the [n, scales * features]
// output or upstream gradient: each slab pass reads a strided slice of them from memory.
constexpr int64_t kPrefetchPoints = 4 * kLanes;

// The cells of kLanes consecutive points (lane l: point first + l) in the six planes of a scale.
// With q_hw the values of the cell's nodes (h, w: 0 lower, 1 upper, along height and width), a
// sample is sum w_hw q_hw, its derivative along the width coordinate
// dx0 (q_01 - q_00) + dx1 (q_11 - q_10) and along the height coordinate
// dy0 (q_10 - q_00) + dy1 (q_11 - q_01); the derivatives are zero at or past the border.
struct alignas(64) BlockCells {
    int32_t node[kPlanesPerScale][kLanes];  // slab index of the (0, 0) node: row * width + column
    float w00[kPlanesPerScale][kLanes], w01[kPlanesPerScale][kLanes];
    float w10[kPlanesPerScale][kLanes], w11[kPlanesPerScale][kLanes];
    float dx0[kPlanesPerScale][kLanes], dx1[kPlanesPerScale][kLanes];
    float dy0[kPlanesPerScale][kLanes], dy1[kPlanesPerScale][kLanes];
};

// The cells of points first .. first + count - 1 (count <= kLanes) of coords [n, 4] in scale s.
void block_cells(const Slabs& slabs, int64_t scale, const float* coords, int64_t first,
                 int64_t count, BlockCells& cells);

// The first `count` (<= kLanes) floats of `source` as Lanes, zero beyond; and the reverse.
inline Lanes load_lanes(const float* source, int64_t count) {
    if (count == kLanes) return Lanes::load(source);
    Lanes lanes{};
    for (int64_t f = 0; f < count; ++f) lanes[f] = source[f];
    return lanes;
}
inline void store_lanes(float* target, Lanes lanes, int64_t count) {
    if (count == kLanes) {
        lanes.store(target);
        return;
    }
    for (int64_t f = 0; f < count; ++f) target[f] = lanes[f];
}

// Bilinear sample of plane k of a block's cells for lane l, in the slab at `slab` of `width`.
inline Lanes sample(const Lanes* slab, int64_t width, const BlockCells& cells, int k, int l) {
    const Lanes* q = slab + cells.node[k][l];
    return q[0] * cells.w00[k][l] + q[1] * cells.w01[k][l] + q[width] * cells.w10[k][l] +
           q[width + 1] * cells.w11[k][l];
}

// out [n, scales * features]: per scale the product of the six samples, scales side by side.
void hexplane_forward(const float* coords, int64_t n, const Slabs& slabs, float* out);

// Given grad_out [n, scales * features], writes grad_coords [n, 3] (x, y, z; time receives no
// gradient) and every plane's gradient grad_planes[p] ([features, height, width], overwritten).
void hexplane_backward(const float* coords, int64_t n, const Slabs& slabs, const float* grad_out,
                       float* grad_coords, const std::vector<float*>& grad_planes);

}  // namespace surgsplat

// The slab layout of the planes and the cells of a block of points.
#include <algorithm>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "common.h"

namespace surgsplat {
namespace {

// Positions of kLanes coordinates along an axis of `nodes` >= 2: between nodes lo and lo + 1,
// the upper one weighted frac, and dfrac = d frac / d coordinate.
struct AxisLanes {
    LanesI lo;
    Lanes frac, dfrac;
};

// -1 and 1 are the first and last node (align_corners=True); outside values clamp to the border,
// where, as in grid_sample, the derivative is zero (NaN counts as -1).
AxisLanes axis_lanes(Lanes coord, int64_t nodes) {
    const float half_span = 0.5f * static_cast<float>(nodes - 1);
    const float last = static_cast<float>(nodes - 1);
    const Lanes u = (coord + 1.0f) * half_span;
    const LanesI inside = (u > 0.0f) & (u < last);
    const Lanes clamped = select(inside, u, select(u >= last, Lanes::all(last), Lanes{}));
    AxisLanes axis;
    const LanesI truncated = to_int(clamped);
    const int32_t top = static_cast<int32_t>(nodes - 2);
    axis.lo = select(truncated > top, LanesI::all(top), truncated);
    axis.frac = clamped - to_float(axis.lo);
    axis.dfrac = select(inside, Lanes::all(half_span), Lanes{});
    return axis;
}

// The x, y, z and t coordinates of points first .. first + count - 1 (count <= kLanes) of
// coords [n, 4], one point per lane (zero beyond count), transposed through a small array.
void load_coordinates(const float* coords, int64_t first, int64_t count, Lanes (&axis)[kAxes]) {
    alignas(64) float lanes[kAxes][kLanes] = {};
    for (int64_t l = 0; l < count; ++l)
        for (int a = 0; a < kAxes; ++a) lanes[a][l] = coords[(first + l) * kAxes + a];
    for (int a = 0; a < kAxes; ++a) axis[a] = Lanes::load(lanes[a]);
}

template <typename T>
void store(T (&lanes)[kLanes], const Pack<T>& value) {
    value.store(lanes);
}

}  // namespace

Slabs::Slabs(std::vector<PlaneView> views, int64_t features_)
    : features(features_), chunks((features_ + kLanes - 1) / kLanes), planes(std::move(views)) {
    start.assign(planes.size() + 1, 0);
    rows.assign(planes.size() + 1, 0);
    nodes.assign(planes.size() / kPlanesPerScale, {0, 0, 0, 0});
    for (size_t p = 0; p < planes.size(); ++p) {
        const PlaneView& view = planes[p];
        if (view.height * view.width >= std::numeric_limits<int32_t>::max())
            throw std::invalid_argument("planes[" + std::to_string(p) + "]: too many nodes");
        start[p + 1] = start[p] + view.height * view.width * chunks;
        rows[p + 1] = rows[p] + view.height;
        std::array<int64_t, kAxes>& count = nodes[p / kPlanesPerScale];
        const int k = static_cast<int>(p % kPlanesPerScale);
        for (const auto& [axis, size] : {std::pair{kWidthAxis[k], view.width},
                                         std::pair{kHeightAxis[k], view.height}}) {
            if (count[axis] != 0 && count[axis] != size)
                throw std::invalid_argument(
                    "planes[" + std::to_string(p) + "]: " + std::to_string(size) +
                    " nodes along axis " + "xyzt"[axis] + ", other planes of its scale have " +
                    std::to_string(count[axis]));
            count[axis] = size;
        }
    }
}

std::unique_ptr<Lanes[]> Slabs::allocate(int64_t copies) const {
    return std::unique_ptr<Lanes[]>(new Lanes[static_cast<size_t>(copies * size())]);
}

void Slabs::gather(Lanes* buffer) const {
#pragma omp parallel for schedule(static)
    for (int64_t r = 0; r < rows.back(); ++r) {
        size_t p = 0;
        while (rows[p + 1] <= r) ++p;
        const PlaneView& view = planes[p];
        const int64_t y = r - rows[p], area = view.height * view.width;
        for (int64_t c = 0; c < chunks; ++c) {
            Lanes* row = buffer + slab(static_cast<int64_t>(p), c) + y * view.width;
            std::fill(row, row + view.width, Lanes{});
            const int64_t count = std::min<int64_t>(features - c * kLanes, kLanes);
            for (int64_t f = 0; f < count; ++f) {
                const float* source = view.data + (c * kLanes + f) * area + y * view.width;
                for (int64_t x = 0; x < view.width; ++x) row[x][f] = source[x];
            }
        }
    }
}

void block_cells(const Slabs& slabs, int64_t scale, const float* coords, int64_t first,
                 int64_t count, BlockCells& cells) {
    Lanes coordinate[kAxes];
    load_coordinates(coords, first, count, coordinate);
    AxisLanes axes[kAxes];
    for (int a = 0; a < kAxes; ++a) axes[a] = axis_lanes(coordinate[a], slabs.nodes[scale][a]);
    for (int k = 0; k < kPlanesPerScale; ++k) {
        const AxisLanes& x = axes[kWidthAxis[k]];
        const AxisLanes& y = axes[kHeightAxis[k]];
        const int32_t width = static_cast<int32_t>(slabs.nodes[scale][kWidthAxis[k]]);
        const Lanes gx = 1.0f - x.frac, gy = 1.0f - y.frac;
        store(cells.node[k], y.lo * width + x.lo);
        store(cells.w00[k], gx * gy);
        store(cells.w01[k], x.frac * gy);
        store(cells.w10[k], gx * y.frac);
        store(cells.w11[k], x.frac * y.frac);
        store(cells.dx0[k], gy * x.dfrac);
        store(cells.dx1[k], y.frac * x.dfrac);
        store(cells.dy0[k], gx * y.dfrac);
        store(cells.dy1[k], x.frac * y.dfrac);
    }
}

}  // namespace surgsplat

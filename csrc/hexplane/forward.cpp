// HexPlane forward: per point and scale, the product of the six bilinearly sampled feature
// vectors, scales side by side; one pass per slab (scale, 16 features) over all points.
#include <algorithm>

#include "common.h"

namespace surgsplat {

void hexplane_forward(const float* coords, int64_t n, const Slabs& slabs, float* out) {
    const int64_t features = slabs.features, width = slabs.scales() * features;
    const int64_t blocks = (n + kLanes - 1) / kLanes;
    std::unique_ptr<Lanes[]> values = slabs.allocate(1);
    slabs.gather(values.get());
#pragma omp parallel
    for (int64_t s = 0; s < slabs.scales(); ++s) {
        for (int64_t c = 0; c < slabs.chunks; ++c) {
            const Lanes* slab[kPlanesPerScale];
            int64_t row[kPlanesPerScale];
            for (int k = 0; k < kPlanesPerScale; ++k) {
                slab[k] = values.get() + slabs.slab(s * kPlanesPerScale + k, c);
                row[k] = slabs.nodes[s][kWidthAxis[k]];
            }
            const int64_t count = std::min<int64_t>(features - c * kLanes, kLanes);
            BlockCells cells;
#pragma omp for schedule(static) nowait
            for (int64_t b = 0; b < blocks; ++b) {
                const int64_t first = b * kLanes, points = std::min<int64_t>(n - first, kLanes);
                block_cells(slabs, s, coords, first, points, cells);
                for (int l = 0; l < points; ++l) {
                    float* target = out + (first + l) * width + s * features + c * kLanes;
                    if (first + l + kPrefetchPoints < n)
                        prefetch(target + kPrefetchPoints * width);
                    const Lanes space = sample(slab[0], row[0], cells, 0, l) *
                                        sample(slab[1], row[1], cells, 1, l) *
                                        sample(slab[2], row[2], cells, 2, l);
                    const Lanes time = sample(slab[3], row[3], cells, 3, l) *
                                       sample(slab[4], row[4], cells, 4, l) *
                                       sample(slab[5], row[5], cells, 5, l);
                    const Lanes product = space * time;
                    store_lanes(target, product, count);
                }
            }
        }
    }
}

}  // namespace surgsplat

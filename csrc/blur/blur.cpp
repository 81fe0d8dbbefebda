// The plain blur of float32 planes: each plane is a group of one, loaded and stored by copies.
#include "blur/blur.h"

namespace surgsplat {

void blur_planes(const float* planes, int64_t count, int64_t height, int64_t width,
                 const float* taps, int radius, float* out) {
    struct Copier {
        const float* planes;
        float* out;
        int64_t height, width;

        void load(int64_t plane, int64_t y, float* const* rows) const {
            const float* src = planes + (plane * height + y) * width;
            std::copy(src, src + width, rows[0]);
        }
        void store(int64_t plane, int64_t y, const float* const* rows) const {
            std::copy(rows[0], rows[0] + width, out + (plane * height + y) * width);
        }
    };
    blur_streamed(count, 1, height, width, taps, radius,
                  [&] { return Copier{planes, out, height, width}; });
}

}  // namespace surgsplat

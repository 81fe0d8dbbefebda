// SSIM map, its weighted sum (the score) and their backward on the blur stream. The map is
// S = a1 a2 / (b1 b2) with a1 = 2 mx my + c1, a2 = 2 (sxy - mx my) + c2, b1 = mx^2 + my^2 + c1,
// b2 = (sxx - mx^2) + (syy - my^2) + c2, where mx, my, sxx, syy, sxy are the blurred x, y, x^2,
// y^2, xy of one channel. E[x^2] and E[y^2] enter S only through their sum in b2, and the blur
// is linear, so four planes per channel suffice: x, y, x^2 + y^2, xy. Forward: the stream loads
// them from the image rows and stores the blurred moments, the map row and its weighted sum.
// Backward: it loads the derivatives of the loss with respect to the four moments, blurs them
// (the blur is its own adjoint) and stores the chain rule through x^2 + y^2 and xy into the
// image gradients.
// Images are interleaved [H, W, C]; rows of one channel are gathered to contiguous rows first,
// since the compiler does not vectorise loads and stores at a run-time stride.
#include <algorithm>
#include <vector>

#include "blur/blur.h"

namespace surgsplat {
namespace {

struct Terms {
    float a1, a2, b1, b2;
};

// ssq = E[x^2] + E[y^2]
inline Terms ssim_terms(float mx, float my, float ssq, float sxy, float c1, float c2) {
    const float mxy = mx * my, msq = mx * mx + my * my;
    return {2.0f * mxy + c1, 2.0f * (sxy - mxy) + c2, msq + c1, (ssq - msq) + c2};
}

void gather(const float* src, int64_t stride, int64_t width, float* __restrict dst) {
    for (int64_t x = 0; x < width; ++x) dst[x] = src[x * stride];
}

void scatter(const float* src, int64_t stride, int64_t width, float* __restrict dst) {
    for (int64_t x = 0; x < width; ++x) dst[x * stride] = src[x];
}

// One row of the four moment planes of a channel: E[x], E[y], E[x^2] + E[y^2], E[xy].
struct MomentRow {
    const float* __restrict mx;
    const float* __restrict my;
    const float* __restrict ssq;
    const float* __restrict sxy;
};

// Where an image's channel rows and the moment planes [4, C, H, W] are.
struct Layout {
    int64_t height, width, channels;

    int64_t values() const { return height * width * channels; }  // per moment
    const float* image_row(const float* image, int64_t c, int64_t y) const {
        return image + y * width * channels + c;
    }
    float* image_row(float* image, int64_t c, int64_t y) const {
        return image + y * width * channels + c;
    }
    int64_t plane_row(int64_t c, int64_t y) const { return (c * height + y) * width; }
    MomentRow moment_row(const float* moments, int64_t c, int64_t y) const {
        const float* row = moments + plane_row(c, y);
        const int64_t n = values();
        return {row, row + n, row + 2 * n, row + 3 * n};
    }
};

void ssim_row(MomentRow m, int64_t width, float c1, float c2, float* __restrict out) {
    for (int64_t x = 0; x < width; ++x) {
        const Terms t = ssim_terms(m.mx[x], m.my[x], m.ssq[x], m.sxy[x], c1, c2);
        out[x] = (t.a1 * t.a2) / (t.b1 * t.b2);
    }
}

// dL/d mx, dL/d my, dL/d ssq, dL/d sxy of one row, given dL/dS = u.
void ssim_grad_row(MomentRow m, const float* __restrict u, int64_t width, float c1, float c2,
                   float* __restrict gx, float* __restrict gy, float* __restrict gsq,
                   float* __restrict gxy) {
    for (int64_t x = 0; x < width; ++x) {
        const float mx = m.mx[x], my = m.my[x];
        const Terms t = ssim_terms(mx, my, m.ssq[x], m.sxy[x], c1, c2);
        const float inv_b1 = 1.0f / t.b1, inv_b2 = 1.0f / t.b2;
        const float inv_b = inv_b1 * inv_b2, score = t.a1 * t.a2 * inv_b;
        // dS/da1 = a2 inv_b, dS/da2 = a1 inv_b, dS/db1 = -S / b1, dS/db2 = -S / b2;
        // d(a1, a2, b1, b2)/d mx = (2 my, -2 my, 2 mx, -2 mx), symmetric in x <-> y
        const float along_a = 2.0f * u[x] * (t.a2 - t.a1) * inv_b;
        const float along_b = 2.0f * u[x] * score * (inv_b2 - inv_b1);
        gx[x] = my * along_a + mx * along_b;
        gy[x] = mx * along_a + my * along_b;
        gsq[x] = -u[x] * score * inv_b2;
        gxy[x] = 2.0f * u[x] * t.a1 * inv_b;
    }
}

// dL/da for an image a that enters S through its mean (the blurred gradient h_mean), x^2 + y^2
// (hsq) and the product with the other image b (hxy): for x, h_mean = hx and b = y; for y, the
// reverse.
void chain_row(const float* __restrict a, const float* __restrict b,
               const float* __restrict h_mean, const float* __restrict hsq,
               const float* __restrict hxy, int64_t width, float* __restrict da) {
    for (int64_t x = 0; x < width; ++x) da[x] = h_mean[x] + 2.0f * a[x] * hsq[x] + b[x] * hxy[x];
}

// sum_x w[x] v[x] (w null: all ones): float partial sums in 16 lanes, then double.
double row_sum(const float* w, const float* v, int64_t width) {
    using blur_detail::Lanes;
    using blur_detail::kLanes;
    using blur_detail::load;
    Lanes acc{};
    int64_t x = 0;
    for (; x + kLanes <= width; x += kLanes)
        acc += w == nullptr ? load(v + x) : load(w + x) * load(v + x);
    double sum = 0.0;
    for (int64_t i = 0; i < kLanes; ++i) sum += acc[i];
    for (; x < width; ++x) sum += w == nullptr ? v[x] : static_cast<double>(w[x]) * v[x];
    return sum;
}

// row[x] *= image_mask[y, x], unless image_mask [height, width] is null.
void mask_row(float* __restrict row, const float* image_mask, int64_t y, int64_t width) {
    if (image_mask == nullptr) return;
    const float* mask = image_mask + y * width;
    for (int64_t x = 0; x < width; ++x) row[x] *= mask[x];
}

struct ForwardWorker {
    Layout layout;
    const float *pred, *gt, *weights, *image_mask;
    float *moments, *map;
    double* row_sums;  // [C, H]
    float c1, c2;
    std::vector<float> values;  // one map row

    void load(int64_t c, int64_t y, float* const* rows) {
        const int64_t width = layout.width;
        gather(layout.image_row(pred, c, y), layout.channels, width, rows[0]);
        gather(layout.image_row(gt, c, y), layout.channels, width, rows[1]);
        mask_row(rows[0], image_mask, y, width);
        mask_row(rows[1], image_mask, y, width);
        const float* __restrict a = rows[0];
        const float* __restrict b = rows[1];
        float* __restrict squares = rows[2];
        float* __restrict product = rows[3];
        for (int64_t x = 0; x < width; ++x) {
            squares[x] = a[x] * a[x] + b[x] * b[x];
            product[x] = a[x] * b[x];
        }
    }

    void store(int64_t c, int64_t y, const float* const* rows) {
        const int64_t width = layout.width, n = layout.values(), first = layout.plane_row(c, y);
        for (int q = 0; q < 4; ++q) std::copy(rows[q], rows[q] + width, moments + q * n + first);
        ssim_row(layout.moment_row(moments, c, y), width, c1, c2, values.data());
        if (map != nullptr)
            scatter(values.data(), layout.channels, width, layout.image_row(map, c, y));
        row_sums[c * layout.height + y] =
            row_sum(weights == nullptr ? nullptr : weights + y * width, values.data(), width);
    }
};

struct BackwardWorker {
    Layout layout;
    const float *pred, *gt, *moments;
    SsimUpstream upstream;
    const float* image_mask;
    float *grad_pred, *grad_gt;  // either null when not wanted
    float c1, c2;
    std::vector<float> scratch;  // three rows: dL/dS / x, y, an image's gradient

    void load(int64_t c, int64_t y, float* const* rows) {
        const int64_t width = layout.width;
        float* __restrict u = scratch.data();
        if (upstream.grad_map != nullptr) {
            gather(layout.image_row(upstream.grad_map, c, y), layout.channels, width, u);
        } else if (upstream.weights != nullptr) {
            const float* w = upstream.weights + y * width;
            for (int64_t x = 0; x < width; ++x) u[x] = upstream.grad_score * w[x];
        } else {
            std::fill(u, u + width, upstream.grad_score);
        }
        ssim_grad_row(layout.moment_row(moments, c, y), u, width, c1, c2, rows[0], rows[1],
                      rows[2], rows[3]);
    }

    void store(int64_t c, int64_t y, const float* const* rows) {
        const int64_t width = layout.width;
        float *a = scratch.data(), *b = a + width;
        gather(layout.image_row(pred, c, y), layout.channels, width, a);
        gather(layout.image_row(gt, c, y), layout.channels, width, b);
        // the images were masked before filtering: the chain rule masks their gradients too
        mask_row(a, image_mask, y, width);
        mask_row(b, image_mask, y, width);
        if (grad_pred != nullptr) store_gradient(a, b, rows[0], rows, c, y, grad_pred);
        if (grad_gt != nullptr) store_gradient(b, a, rows[1], rows, c, y, grad_gt);
    }

    void store_gradient(const float* image, const float* other, const float* h_mean,
                        const float* const* rows, int64_t c, int64_t y, float* grad) {
        const int64_t width = layout.width;
        float* row = scratch.data() + 2 * width;
        chain_row(image, other, h_mean, rows[2], rows[3], width, row);
        mask_row(row, image_mask, y, width);
        scatter(row, layout.channels, width, layout.image_row(grad, c, y));
    }
};

}  // namespace

double ssim_forward(const float* pred, const float* gt, int64_t height, int64_t width,
                    int64_t channels, const float* taps, int radius, float c1, float c2,
                    const float* weights, const float* image_mask, float* moments,
                    float* map) {
    const Layout layout{height, width, channels};
    std::vector<double> row_sums(channels * height);
    blur_streamed(channels, 4, height, width, taps, radius, [&] {
        return ForwardWorker{layout, pred, gt, weights, image_mask, moments, map,
                             row_sums.data(), c1, c2, std::vector<float>(width)};
    });
    double score = 0.0;  // summed in a fixed order: the same result for any thread count
    for (double row : row_sums) score += row;
    return score;
}

void ssim_backward(const float* pred, const float* gt, const float* moments, int64_t height,
                   int64_t width, int64_t channels, const float* taps, int radius, float c1,
                   float c2, const SsimUpstream& upstream, const float* image_mask,
                   float* grad_pred, float* grad_gt) {
    const Layout layout{height, width, channels};
    blur_streamed(channels, 4, height, width, taps, radius, [&] {
        return BackwardWorker{layout, pred, gt, moments, upstream, image_mask, grad_pred,
                              grad_gt, c1, c2, std::vector<float>(3 * width)};
    });
}

}  // namespace surgsplat

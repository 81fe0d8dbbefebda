// Normal consistency; see normals.h.
#include "normals.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace surgsplat {
namespace {

constexpr float kNormEps = 1e-12f;       // torch.nn.functional.normalize's eps
constexpr float kMinCrossSquare = 1e-24f;  // image.pinhole.depth_normals' clamp of |c|^2

struct Vec3 {
    float x, y, z;
};

inline Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator*(float s, Vec3 a) { return {s * a.x, s * a.y, s * a.z}; }
inline float dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 cross(Vec3 a, Vec3 b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float sign_of(float value) {  // without a branch: the signs of noise are unpredictable
    return static_cast<float>((value > 0.0f) - (value < 0.0f));
}

struct Image {
    const float* depth;
    const float* normals;
    const float* ray_x;
    const float* ray_y;
    const bool* mask;
    const float* weights;
    int64_t height, width;

    Vec3 point(int64_t i, int64_t j) const {
        const float d = depth[i * width + j];
        return {d * ray_x[j], d * ray_y[i], d};
    }
};

// One interior pixel's terms: whether it is counted, and if so its tangents, cross product,
// the two unit normals and the weight.
struct Pixel {
    bool counted;
    Vec3 h, v, n_depth, n_render;
    float inverse_cross, sign, render_length, weight;
};

inline Pixel pixel_terms(const Image& image, int64_t i, int64_t j) {
    Pixel p{};
    const int64_t at = i * image.width + j;
    const float* d = image.depth;
    const int64_t w = image.width;
    if (!image.mask[at] || !(d[at] > 0.0f && d[at - 1] > 0.0f && d[at + 1] > 0.0f &&
                             d[at - w] > 0.0f && d[at + w] > 0.0f))
        return p;
    p.h = image.point(i, j + 1) - image.point(i, j - 1);
    p.v = image.point(i + 1, j) - image.point(i - 1, j);
    const Vec3 c = cross(p.h, p.v);
    const float square = dot(c, c);
    if (!(square > kMinCrossSquare)) return p;
    p.counted = true;
    p.inverse_cross = 1.0f / std::sqrt(square);
    p.sign = dot(c, image.point(i, j)) < 0.0f ? -1.0f : 1.0f;
    p.n_depth = (p.sign * p.inverse_cross) * c;
    const float* n = image.normals + 3 * at;
    const Vec3 rendered{n[0], n[1], n[2]};
    p.render_length = std::sqrt(dot(rendered, rendered));
    p.n_render = (1.0f / std::max(p.render_length, kNormEps)) * rendered;
    p.weight = image.weights ? image.weights[at] : 1.0f;
    return p;
}

inline float l1(Vec3 a) { return std::fabs(a.x) + std::fabs(a.y) + std::fabs(a.z); }

}  // namespace

NormalConsistency normal_consistency_forward(const float* depth, const float* normals,
                                             const float* ray_x, const float* ray_y,
                                             const bool* mask, const float* weights,
                                             int64_t height, int64_t width) {
    const Image image{depth, normals, ray_x, ray_y, mask, weights, height, width};
    double sum = 0.0;
    int64_t count = 0;
#pragma omp parallel for schedule(static) reduction(+ : sum, count)
    for (int64_t i = 1; i < height - 1; ++i) {
        double row = 0.0;
        for (int64_t j = 1; j < width - 1; ++j) {
            const Pixel p = pixel_terms(image, i, j);
            if (!p.counted) continue;
            row += p.weight * l1(p.n_depth - p.n_render);
            ++count;
        }
        sum += row;
    }
    return {sum, count};
}

void normal_consistency_backward(const float* depth, const float* normals, const float* ray_x,
                                 const float* ray_y, const bool* mask, const float* weights,
                                 int64_t height, int64_t width, float grad_sum,
                                 float* grad_depth, float* grad_normals) {
    const Image image{depth, normals, ray_x, ray_y, mask, weights, height, width};
    const int64_t pixels = height * width;
    // Pass 1, per pixel: the gradients of its tangents h and v (zero where not counted) and of
    // its rendered normal. Pass 2 gathers each point's gradient from its four neighbours'
    // tangents, so that no two threads write one pixel.
    // Kept between calls: fresh pages for every step cost more than the passes' arithmetic.
    static thread_local std::vector<Vec3> tangent_grads;
    if (grad_depth && tangent_grads.size() < static_cast<size_t>(2 * pixels))
        tangent_grads.resize(2 * pixels);
    Vec3* grad_h = grad_depth ? tangent_grads.data() : nullptr;
    Vec3* grad_v = grad_depth ? grad_h + pixels : nullptr;
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < height; ++i) {
        for (int64_t j = 0; j < width; ++j) {
            const int64_t at = i * width + j;
            const bool interior = i > 0 && i < height - 1 && j > 0 && j < width - 1;
            const Pixel p = interior ? pixel_terms(image, i, j) : Pixel{};
            Vec3 a{0.0f, 0.0f, 0.0f};  // the gradient of n_depth
            if (p.counted) {
                const Vec3 diff = p.n_depth - p.n_render;
                a = (grad_sum * p.weight) * Vec3{sign_of(diff.x), sign_of(diff.y),
                                                 sign_of(diff.z)};
            }
            if (grad_normals) {
                Vec3 g{0.0f, 0.0f, 0.0f};
                if (p.counted) {  // n_render's gradient is -a
                    if (p.render_length > kNormEps)
                        g = (1.0f / p.render_length) * (dot(p.n_render, a) * p.n_render - a);
                    else
                        g = (-1.0f / kNormEps) * a;
                }
                grad_normals[3 * at] = g.x;
                grad_normals[3 * at + 1] = g.y;
                grad_normals[3 * at + 2] = g.z;
            }
            if (grad_depth) {
                Vec3 gh{0.0f, 0.0f, 0.0f}, gv{0.0f, 0.0f, 0.0f};
                if (p.counted) {
                    const Vec3 gc = (p.sign * p.inverse_cross) *
                                    (a - dot(p.n_depth, a) * p.n_depth);  // of c = h x v
                    gh = cross(p.v, gc);
                    gv = cross(gc, p.h);
                }
                grad_h[at] = gh;
                grad_v[at] = gv;
            }
        }
    }
    if (!grad_depth) return;
    const Vec3 zero{0.0f, 0.0f, 0.0f};
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < height; ++i) {
        for (int64_t j = 0; j < width; ++j) {
            const int64_t at = i * width + j;
            // P(i, j) is the right neighbour of (i, j-1), the left of (i, j+1), the lower of
            // (i-1, j) and the upper of (i+1, j)
            const Vec3 left = j > 0 ? grad_h[at - 1] : zero;
            const Vec3 right = j < width - 1 ? grad_h[at + 1] : zero;
            const Vec3 up = i > 0 ? grad_v[at - width] : zero;
            const Vec3 down = i < height - 1 ? grad_v[at + width] : zero;
            const Vec3 g = (left - right) - (down - up);
            grad_depth[at] = g.x * ray_x[j] + g.y * ray_y[i] + g.z;
        }
    }
}

}  // namespace surgsplat

// Shared definitions of the tile rasterizer: tile geometry, the compositing constants and the
// per-pixel Gaussian evaluation that forward and backward must compute identically.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

namespace surgsplat {

constexpr int kTile = 16;                    // tile edge in pixels
constexpr int kTilePixels = kTile * kTile;   // pixels per tile
constexpr float kAlphaMax = 0.99f;           // alpha = min(0.99, o * exp(-q / 2))
constexpr float kAlphaMin = 1.0f / 255.0f;   // contributions below this are skipped
constexpr float kTransmittanceMin = 1e-4f;   // compositing stops below this transmittance

// exp(x) for x <= 0 without libm, so that loops over pixels vectorise: x = n ln2 + r with
// |r| <= ln2 / 2, exp(r) by its degree-6 Taylor polynomial (relative error < 2e-7).
inline float fast_exp(float x) {
    x = x < -87.0f ? -87.0f : x;
    const float n = std::nearbyint(x * 1.44269504088896341f);
    const float r = x - n * 0.693145751953125f - n * 1.42860682030941723e-06f;
    float p = 1.0f / 720.0f;
    p = p * r + 1.0f / 120.0f;
    p = p * r + 1.0f / 24.0f;
    p = p * r + 1.0f / 6.0f;
    p = p * r + 0.5f;
    p = p * r + 1.0f;
    p = p * r + 1.0f;
    const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
    float scale;
    std::memcpy(&scale, &bits, sizeof(scale));
    return p * scale;
}

// Screen-space Gaussian as the kernels read it.
struct Splat {
    float mx, my;     // mean in pixels
    float a, b, c;    // conic: q = a dx^2 + 2 b dx dy + c dy^2
    float opacity;
};

// Inclusive pixel box outside which a Gaussian's alpha is below kAlphaMin.
struct PixelBox {
    int32_t x0, y0, x1, y1;
};

// Tile lists: Gaussians overlapping tile t are ids[offsets[t] .. offsets[t+1]), nearest first.
struct TileBins {
    int tiles_x = 0, tiles_y = 0;
    std::vector<int32_t> offsets;   // [tiles + 1]
    std::vector<int32_t> ids;       // [total overlaps]
    std::vector<PixelBox> boxes;    // [N], x1 < x0 when the Gaussian is not drawn
};

TileBins bin_gaussians(const float* means2d, const float* conics, const float* opacities,
                       const float* depths, const int32_t* radii, int64_t n, int width,
                       int height);

void rasterize_forward(const float* means2d, const float* conics, const float* opacities,
                       const float* features, int64_t channels, const TileBins& bins,
                       int width, int height, float* image, float* transmittance,
                       int32_t* last_entry);

void rasterize_backward(const float* means2d, const float* conics, const float* opacities,
                        const float* features, int64_t n, int64_t channels,
                        const TileBins& bins, int width, int height,
                        const float* transmittance, const int32_t* last_entry,
                        const float* grad_image, const float* grad_alpha,
                        float* grad_means2d, float* grad_conics, float* grad_opacities,
                        float* grad_features, float* abs_grad_means2d);

}  // namespace surgsplat

// The limit probe of the benchmarks: the rasterizer's per-pixel compositing arithmetic with
// nothing around it, compiled with the same flags as the kernels of its ISA variant.
#pragma once

#include <cstdint>

namespace surgsplat {

// Composites `gaussians` fixed Gaussians (pseudo-random, inside one 16x16 tile, `channels`
// features each) front to back over every pixel of `tiles` tiles, in parallel over tiles: no
// binning, no tile lists, no culling and no early stop, so it evaluates exactly
// tiles * gaussians * 256 (Gaussian, pixel) pairs. Returns the sum of the composited values,
// which keeps the work from being optimised away.
double composite_probe(int64_t tiles, int64_t gaussians, int64_t channels);

}  // namespace surgsplat

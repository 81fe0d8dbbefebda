// EndoPlanar's normal consistency (Eq. 7-8, surgsplat/methods/endoplanar/normal_consistency.py),
// forward and backward over the pixels of one image. Per interior pixel p = (i, j), with the
// back-projected points P(i, j) = depth(i, j) * (ray_x[j], ray_y[i], 1):
//   h = P(i, j+1) - P(i, j-1),  v = P(i+1, j) - P(i-1, j),  c = h x v,
//   n_depth = sign(c . P(i, j)) c / |c|  (facing away from the camera; sign(0) = +1),
//   n_render = normals(p) / max(|normals(p)|, 1e-12)  (torch.nn.functional.normalize),
//   counted(p) = mask(p), the five depths > 0 and |c|^2 > 1e-24  (image.pinhole.depth_normals),
//   sum = sum over counted p of weights(p) * |n_depth - n_render|_1.
// The border pixels are never counted. Gradients flow to depth (through n_depth; the facing sign
// and the counted set are constants) and to normals; none to the rays, mask or weights.
#pragma once

#include <cstdint>

namespace surgsplat {

struct NormalConsistency {
    double sum;     // the weighted L1 sum over the counted pixels
    int64_t count;  // the counted pixels
};

// depth [height, width], normals [height, width, 3], ray_x [width], ray_y [height],
// mask [height, width], weights [height, width] or null (ones).
NormalConsistency normal_consistency_forward(const float* depth, const float* normals,
                                             const float* ray_x, const float* ray_y,
                                             const bool* mask, const float* weights,
                                             int64_t height, int64_t width);

// Gradients of grad_sum * sum with respect to depth [height, width] and normals
// [height, width, 3], each overwritten unless null.
void normal_consistency_backward(const float* depth, const float* normals, const float* ray_x,
                                 const float* ray_y, const bool* mask, const float* weights,
                                 int64_t height, int64_t width, float grad_sum,
                                 float* grad_depth, float* grad_normals);

}  // namespace surgsplat

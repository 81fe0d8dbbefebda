// EWA projection of 3D Gaussians to screen-space ellipses, forward and backward, one Gaussian per
// loop iteration. The contract is surgsplat/render/project.py's PyTorch reference: same culling,
// same clamping, same radii, gradients of every output.
#pragma once

#include <cstdint>

namespace surgsplat {

// Pinhole camera and projection settings shared by both passes.
struct ProjectCamera {
    float rotation[9];     // world-to-camera rotation W, row-major
    float translation[3];  // world-to-camera translation t: x_cam = W x + t
    float fx, fy, cx, cy;  // pinhole intrinsics in pixels
    int width, height;     // image size in pixels
    float near;            // Gaussians with camera depth <= near are culled
    float lowpass;         // pixels^2 added to the 2D covariance diagonal
    float fov_clamp;       // Jacobian evaluated within fov_clamp times the field of view
};

// Inputs: means [n, 3], scales [n, 3] (linear), quats [n, 4] (w, x, y, z; normalised here).
// Outputs: means2d [n, 2], conics [n, 3], depths [n], radii [n] (0 = culled), means_camera
// [n, 3], rotations_camera [n, 3, 3] (W R, the Gaussian's axes as columns).
void project_forward(const float* means, const float* scales, const float* quats, int64_t n,
                     const ProjectCamera& camera, float* means2d, float* conics, float* depths,
                     int32_t* radii, float* means_camera, float* rotations_camera);

// Gaussians per block of the camera gradients' reduction (see project_backward).
constexpr int64_t kCameraBlock = 1024;

// Gradients of a scalar loss with respect to means, scales and quats, and to the camera, given
// its gradients with respect to every differentiable output of project_forward. The camera's:
// grad_world_to_camera [4, 4] (rotation block and translation column, as free entries; the last
// row 0) and grad_intrinsics [4] (fx, fy, cx, cy), each a sum over the Gaussians: in double over
// blocks of kCameraBlock Gaussians, then over the blocks in order, so the same for any number of
// threads.
void project_backward(const float* means, const float* scales, const float* quats, int64_t n,
                      const ProjectCamera& camera, const float* grad_means2d,
                      const float* grad_conics, const float* grad_depths,
                      const float* grad_means_camera, const float* grad_rotations_camera,
                      float* grad_means, float* grad_scales, float* grad_quats,
                      float* grad_world_to_camera, float* grad_intrinsics);

}  // namespace surgsplat

// EWA projection forward and backward (see project.h). Per Gaussian:
//   m = W p + t,  z_s = z if z > near else near,  Jacobian J at the FOV-clamped (x, y),
//   R = rotation(q / |q|),  M = J W R diag(s) [2, 3],  Sigma2d = M M^T + lowpass I,
//   conic = Sigma2d^-1 (Sigma2d itself, unchanged, when culled: the reference's det_safe = 1),
//   means2d = (fx x / z_s + cx, fy y / z_s + cy).
// The backward runs the same chain in reverse, one Gaussian at a time; only the camera's
// gradients are shared, summed per block of Gaussians and then over the blocks in order.
#include "project/project.h"

#include <algorithm>
#include <cmath>
#include <memory>

namespace surgsplat {
namespace {

constexpr float kNormEps = 1e-12f;  // torch.nn.functional.normalize's eps
constexpr int kCameraGrads = 16;    // W (9), t (3), fx, fy, cx, cy

struct Mat3 {
    float m[3][3];
};

Mat3 camera_rotation(const ProjectCamera& camera) {
    Mat3 w;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) w.m[i][j] = camera.rotation[3 * i + j];
    return w;
}

Mat3 product(const Mat3& a, const Mat3& b) {
    Mat3 c;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            c.m[i][j] = a.m[i][0] * b.m[0][j] + a.m[i][1] * b.m[1][j] + a.m[i][2] * b.m[2][j];
    return c;
}

// Rotation matrix of the unit quaternion (w, x, y, z).
Mat3 quaternion_matrix(float w, float x, float y, float z) {
    return {{{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
             {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
             {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}}};
}

// Everything the forward computes for one Gaussian that the backward needs again.
struct GaussianProjection {
    float q[4], q_norm;       // normalised quaternion and the norm divided by
    Mat3 rotation;            // R
    Mat3 rotation_camera;     // W R
    float x, y, z, z_safe;    // camera-space mean and the depth used for projection
    bool in_front;
    float x_clamped, y_clamped;
    bool x_inside, y_inside;  // the FOV clamp did not bind (gradient flows to x, y)
    float j00, j02, j11, j12; // Jacobian entries (J01 = J10 = 0)
    float half[2][3];         // M = J W R diag(s)
    float cov_xx, cov_xy, cov_yy, det;
    bool valid;               // in front with a positive-definite 2D covariance
};

GaussianProjection project_one(const float* p, const float* s, const float* quat,
                               const ProjectCamera& camera, const Mat3& w) {
    GaussianProjection g;
    const float norm = std::sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] +
                                 quat[3] * quat[3]);
    g.q_norm = std::max(norm, kNormEps);
    for (int i = 0; i < 4; ++i) g.q[i] = quat[i] / g.q_norm;
    g.rotation = quaternion_matrix(g.q[0], g.q[1], g.q[2], g.q[3]);
    g.rotation_camera = product(w, g.rotation);

    const float* t = camera.translation;
    g.x = w.m[0][0] * p[0] + w.m[0][1] * p[1] + w.m[0][2] * p[2] + t[0];
    g.y = w.m[1][0] * p[0] + w.m[1][1] * p[1] + w.m[1][2] * p[2] + t[1];
    g.z = w.m[2][0] * p[0] + w.m[2][1] * p[1] + w.m[2][2] * p[2] + t[2];
    g.in_front = g.z > camera.near;
    g.z_safe = g.in_front ? g.z : camera.near;

    const float tan_x = camera.fov_clamp * 0.5f * camera.width / camera.fx;
    const float tan_y = camera.fov_clamp * 0.5f * camera.height / camera.fy;
    const float u = g.x / g.z_safe, v = g.y / g.z_safe;
    g.x_inside = u >= -tan_x && u <= tan_x;
    g.y_inside = v >= -tan_y && v <= tan_y;
    g.x_clamped = std::clamp(u, -tan_x, tan_x) * g.z_safe;
    g.y_clamped = std::clamp(v, -tan_y, tan_y) * g.z_safe;
    const float inv_z = 1.0f / g.z_safe, inv_z2 = inv_z * inv_z;
    g.j00 = camera.fx * inv_z;
    g.j02 = -camera.fx * g.x_clamped * inv_z2;
    g.j11 = camera.fy * inv_z;
    g.j12 = -camera.fy * g.y_clamped * inv_z2;

    const Mat3& rc = g.rotation_camera;
    for (int k = 0; k < 3; ++k) {
        g.half[0][k] = (g.j00 * rc.m[0][k] + g.j02 * rc.m[2][k]) * s[k];
        g.half[1][k] = (g.j11 * rc.m[1][k] + g.j12 * rc.m[2][k]) * s[k];
    }
    const float* m0 = g.half[0];
    const float* m1 = g.half[1];
    g.cov_xx = m0[0] * m0[0] + m0[1] * m0[1] + m0[2] * m0[2] + camera.lowpass;
    g.cov_xy = m0[0] * m1[0] + m0[1] * m1[1] + m0[2] * m1[2];
    g.cov_yy = m1[0] * m1[0] + m1[1] * m1[1] + m1[2] * m1[2] + camera.lowpass;
    g.det = g.cov_xx * g.cov_yy - g.cov_xy * g.cov_xy;
    g.valid = g.in_front && g.det > 0.0f;
    return g;
}

// 3-sigma radius in pixels, or 0 when culled (the reference's rule, in the same order).
int32_t radius(const GaussianProjection& g, float mean_x, float mean_y,
               const ProjectCamera& camera) {
    const float half_trace = 0.5f * (g.cov_xx + g.cov_yy);
    const float big_eigen =
        half_trace + std::sqrt(std::max(half_trace * half_trace - g.det, 0.01f));
    const float r = std::ceil(3.0f * std::sqrt(big_eigen));
    const bool on_screen = mean_x + r > 0 && mean_x - r < camera.width && mean_y + r > 0 &&
                           mean_y - r < camera.height;
    if (!(g.valid && on_screen && std::isfinite(r))) return 0;
    return static_cast<int32_t>(std::min(r, 2.0f * std::max(camera.width, camera.height) + 1));
}

// The gradients of Gaussian i (written to grad_means, grad_scales, grad_quats) and its share of
// the camera's, added to camera_grad: W (9, row-major), t (3), fx, fy, cx, cy.
void backward_one(int64_t i, const float* means, const float* scales, const float* quats,
                  const ProjectCamera& camera, const Mat3& w, const float* grad_means2d,
                  const float* grad_conics, const float* grad_depths,
                  const float* grad_means_camera, const float* grad_rotations_camera,
                  float* grad_means, float* grad_scales, float* grad_quats,
                  double* camera_grad) {
    const float* p = means + 3 * i;
    const float* s = scales + 3 * i;
    const GaussianProjection g = project_one(p, s, quats + 4 * i, camera, w);

    // conic -> 2D covariance (det is a constant 1 for culled Gaussians).
    const float ga = grad_conics[3 * i], gb = grad_conics[3 * i + 1],
                gc = grad_conics[3 * i + 2];
    const float det = g.valid ? g.det : 1.0f;
    const float g_det = g.valid
        ? -(ga * g.cov_yy - gb * g.cov_xy + gc * g.cov_xx) / (det * det) : 0.0f;
    const float g_xx = gc / det + g_det * g.cov_yy;
    const float g_yy = ga / det + g_det * g.cov_xx;
    const float g_xy = -gb / det - 2.0f * g_det * g.cov_xy;

    // covariance = M M^T -> M.
    float g_half[2][3];
    for (int k = 0; k < 3; ++k) {
        g_half[0][k] = 2.0f * g_xx * g.half[0][k] + g_xy * g.half[1][k];
        g_half[1][k] = 2.0f * g_yy * g.half[1][k] + g_xy * g.half[0][k];
    }

    // M[r][k] = (J W R)[r][k] s[k] -> Jacobian, scales and W R.
    const Mat3& rc = g.rotation_camera;
    float g_j00 = 0, g_j02 = 0, g_j11 = 0, g_j12 = 0;
    Mat3 g_rc;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) g_rc.m[r][c] = grad_rotations_camera[9 * i + 3 * r + c];
    for (int k = 0; k < 3; ++k) {
        const float a0 = g_half[0][k] * s[k], a1 = g_half[1][k] * s[k];
        g_j00 += a0 * rc.m[0][k];
        g_j02 += a0 * rc.m[2][k];
        g_j11 += a1 * rc.m[1][k];
        g_j12 += a1 * rc.m[2][k];
        g_rc.m[0][k] += g.j00 * a0;
        g_rc.m[1][k] += g.j11 * a1;
        g_rc.m[2][k] += g.j02 * a0 + g.j12 * a1;
        grad_scales[3 * i + k] =
            g_half[0][k] * (g.j00 * rc.m[0][k] + g.j02 * rc.m[2][k]) +
            g_half[1][k] * (g.j11 * rc.m[1][k] + g.j12 * rc.m[2][k]);
    }

    // W R -> R -> normalised quaternion -> quaternion.
    Mat3 g_rot;  // W^T g_rc
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            g_rot.m[r][c] = w.m[0][r] * g_rc.m[0][c] + w.m[1][r] * g_rc.m[1][c] +
                            w.m[2][r] * g_rc.m[2][c];
    const auto& G = g_rot.m;
    const float qw = g.q[0], qx = g.q[1], qy = g.q[2], qz = g.q[3];
    const float g_q[4] = {
        2 * (-qz * G[0][1] + qy * G[0][2] + qz * G[1][0] - qx * G[1][2] - qy * G[2][0] +
             qx * G[2][1]),
        2 * (qy * G[0][1] + qz * G[0][2] + qy * G[1][0] - 2 * qx * G[1][1] - qw * G[1][2] +
             qz * G[2][0] + qw * G[2][1] - 2 * qx * G[2][2]),
        2 * (-2 * qy * G[0][0] + qx * G[0][1] + qw * G[0][2] + qx * G[1][0] + qz * G[1][2] -
             qw * G[2][0] + qz * G[2][1] - 2 * qy * G[2][2]),
        2 * (-2 * qz * G[0][0] - qw * G[0][1] + qx * G[0][2] + qw * G[1][0] -
             2 * qz * G[1][1] + qy * G[1][2] + qx * G[2][0] + qy * G[2][1])};
    const float raw_norm = std::sqrt(quats[4 * i] * quats[4 * i] +
                                     quats[4 * i + 1] * quats[4 * i + 1] +
                                     quats[4 * i + 2] * quats[4 * i + 2] +
                                     quats[4 * i + 3] * quats[4 * i + 3]);
    const float radial = raw_norm > kNormEps
        ? g.q[0] * g_q[0] + g.q[1] * g_q[1] + g.q[2] * g_q[2] + g.q[3] * g_q[3] : 0.0f;
    for (int k = 0; k < 4; ++k) grad_quats[4 * i + k] = (g_q[k] - g.q[k] * radial) / g.q_norm;

    // Jacobian and means2d -> camera-space mean.
    const float inv_z = 1.0f / g.z_safe, inv_z2 = inv_z * inv_z;
    const float gu = grad_means2d[2 * i], gv = grad_means2d[2 * i + 1];
    float g_x = gu * camera.fx * inv_z + grad_means_camera[3 * i];
    float g_y = gv * camera.fy * inv_z + grad_means_camera[3 * i + 1];
    float g_z_safe = -(gu * camera.fx * g.x + gv * camera.fy * g.y) * inv_z2 -
                     (g_j00 * camera.fx + g_j11 * camera.fy) * inv_z2 +
                     2.0f * (g_j02 * camera.fx * g.x_clamped +
                             g_j12 * camera.fy * g.y_clamped) * inv_z2 * inv_z;
    const float g_x_clamped = -g_j02 * camera.fx * inv_z2;
    const float g_y_clamped = -g_j12 * camera.fy * inv_z2;
    if (g.x_inside) g_x += g_x_clamped;
    else g_z_safe += g_x_clamped * (g.x_clamped * inv_z);
    if (g.y_inside) g_y += g_y_clamped;
    else g_z_safe += g_y_clamped * (g.y_clamped * inv_z);
    const float g_z = grad_depths[i] + grad_means_camera[3 * i + 2] +
                      (g.in_front ? g_z_safe : 0.0f);

    // m = W p + t -> p, t; W R and m -> W.
    const float g_m[3] = {g_x, g_y, g_z};
    for (int c = 0; c < 3; ++c)
        grad_means[3 * i + c] = w.m[0][c] * g_x + w.m[1][c] * g_y + w.m[2][c] * g_z;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c)
            camera_grad[3 * r + c] += g_m[r] * p[c] + g_rc.m[r][0] * g.rotation.m[c][0] +
                                      g_rc.m[r][1] * g.rotation.m[c][1] +
                                      g_rc.m[r][2] * g.rotation.m[c][2];
        camera_grad[9 + r] += g_m[r];
    }

    // means2d, the Jacobian and (where it binds) the FOV clamp -> intrinsics:
    // d x_clamped / d fx = -x_clamped / fx when clamped at +-tan_x = +-fov_clamp width / (2 fx).
    camera_grad[12] += (gu * g.x + g_j00) * inv_z - g_j02 * g.x_clamped * inv_z2 -
                       (g.x_inside ? 0.0f : g_x_clamped * g.x_clamped / camera.fx);
    camera_grad[13] += (gv * g.y + g_j11) * inv_z - g_j12 * g.y_clamped * inv_z2 -
                       (g.y_inside ? 0.0f : g_y_clamped * g.y_clamped / camera.fy);
    camera_grad[14] += gu;
    camera_grad[15] += gv;
}

}  // namespace

void project_forward(const float* means, const float* scales, const float* quats, int64_t n,
                     const ProjectCamera& camera, float* means2d, float* conics, float* depths,
                     int32_t* radii, float* means_camera, float* rotations_camera) {
    const Mat3 w = camera_rotation(camera);
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const GaussianProjection g = project_one(means + 3 * i, scales + 3 * i, quats + 4 * i,
                                                 camera, w);
        const float det = g.valid ? g.det : 1.0f;
        conics[3 * i] = g.cov_yy / det;
        conics[3 * i + 1] = -g.cov_xy / det;
        conics[3 * i + 2] = g.cov_xx / det;
        means2d[2 * i] = camera.fx * g.x / g.z_safe + camera.cx;
        means2d[2 * i + 1] = camera.fy * g.y / g.z_safe + camera.cy;
        depths[i] = g.z;
        radii[i] = radius(g, means2d[2 * i], means2d[2 * i + 1], camera);
        means_camera[3 * i] = g.x;
        means_camera[3 * i + 1] = g.y;
        means_camera[3 * i + 2] = g.z;
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) rotations_camera[9 * i + 3 * r + c] = g.rotation_camera.m[r][c];
    }
}

void project_backward(const float* means, const float* scales, const float* quats, int64_t n,
                      const ProjectCamera& camera, const float* grad_means2d,
                      const float* grad_conics, const float* grad_depths,
                      const float* grad_means_camera, const float* grad_rotations_camera,
                      float* grad_means, float* grad_scales, float* grad_quats,
                      float* grad_world_to_camera, float* grad_intrinsics) {
    const Mat3 w = camera_rotation(camera);
    const int64_t blocks = (n + kCameraBlock - 1) / kCameraBlock;
    std::unique_ptr<double[]> partial(new double[kCameraGrads * std::max<int64_t>(blocks, 1)]());
#pragma omp parallel for schedule(static)
    for (int64_t b = 0; b < blocks; ++b) {
        double* camera_grad = partial.get() + kCameraGrads * b;
        for (int64_t i = b * kCameraBlock; i < std::min(n, (b + 1) * kCameraBlock); ++i)
            backward_one(i, means, scales, quats, camera, w, grad_means2d, grad_conics,
                         grad_depths, grad_means_camera, grad_rotations_camera, grad_means,
                         grad_scales, grad_quats, camera_grad);
    }
    double total[kCameraGrads] = {};
    for (int64_t b = 0; b < blocks; ++b)
        for (int k = 0; k < kCameraGrads; ++k) total[k] += partial[kCameraGrads * b + k];
    std::fill(grad_world_to_camera, grad_world_to_camera + 16, 0.0f);
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c)
            grad_world_to_camera[4 * r + c] = static_cast<float>(total[3 * r + c]);
        grad_world_to_camera[4 * r + 3] = static_cast<float>(total[9 + r]);
    }
    for (int k = 0; k < 4; ++k) grad_intrinsics[k] = static_cast<float>(total[12 + k]);
}

}  // namespace surgsplat

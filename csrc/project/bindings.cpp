// Python bindings of the EWA projection.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>

#include "bindings.h"
#include "project/project.h"

namespace nb = nanobind;
using surgsplat::ProjectCamera;

namespace {

// The camera from world_to_camera [4, 4] and the scalar settings.
ProjectCamera make_camera(const In<float>& world_to_camera, float fx, float fy, float cx,
                          float cy, int width, int height, float near, float lowpass,
                          float fov_clamp) {
    expect_size(world_to_camera, 16, "world_to_camera");
    ProjectCamera camera{};
    const float* m = world_to_camera.data();
    for (int r = 0; r < 3; ++r) {
        std::copy(m + 4 * r, m + 4 * r + 3, camera.rotation + 3 * r);
        camera.translation[r] = m[4 * r + 3];
    }
    camera.fx = fx;
    camera.fy = fy;
    camera.cx = cx;
    camera.cy = cy;
    camera.width = width;
    camera.height = height;
    camera.near = near;
    camera.lowpass = lowpass;
    camera.fov_clamp = fov_clamp;
    return camera;
}

size_t check_gaussians(const In<float>& means, const In<float>& scales, const In<float>& quats) {
    if (means.ndim() != 2 || means.shape(1) != 3)
        throw std::invalid_argument("means: expected shape [N, 3]");
    const size_t n = means.shape(0);
    expect_size(scales, 3 * n, "scales");
    expect_size(quats, 4 * n, "quats");
    return n;
}

void forward(In<float> means, In<float> scales, In<float> quats, In<float> world_to_camera,
             float fx, float fy, float cx, float cy, int width, int height, float near,
             float lowpass, float fov_clamp, Out<float> means2d, Out<float> conics,
             Out<float> depths, Out<int32_t> radii, Out<float> means_camera,
             Out<float> rotations_camera) {
    const size_t n = check_gaussians(means, scales, quats);
    const ProjectCamera camera = make_camera(world_to_camera, fx, fy, cx, cy, width, height,
                                             near, lowpass, fov_clamp);
    expect_size(means2d, 2 * n, "means2d");
    expect_size(conics, 3 * n, "conics");
    expect_size(depths, n, "depths");
    expect_size(radii, n, "radii");
    expect_size(means_camera, 3 * n, "means_camera");
    expect_size(rotations_camera, 9 * n, "rotations_camera");
    nb::gil_scoped_release unlocked;
    surgsplat::project_forward(means.data(), scales.data(), quats.data(), n, camera,
                               means2d.data(), conics.data(), depths.data(), radii.data(),
                               means_camera.data(), rotations_camera.data());
}

void backward(In<float> means, In<float> scales, In<float> quats, In<float> world_to_camera,
              float fx, float fy, float cx, float cy, int width, int height, float near,
              float lowpass, float fov_clamp, In<float> grad_means2d, In<float> grad_conics,
              In<float> grad_depths, In<float> grad_means_camera,
              In<float> grad_rotations_camera, Out<float> grad_means, Out<float> grad_scales,
              Out<float> grad_quats, Out<float> grad_world_to_camera,
              Out<float> grad_intrinsics) {
    const size_t n = check_gaussians(means, scales, quats);
    const ProjectCamera camera = make_camera(world_to_camera, fx, fy, cx, cy, width, height,
                                             near, lowpass, fov_clamp);
    expect_size(grad_means2d, 2 * n, "grad_means2d");
    expect_size(grad_conics, 3 * n, "grad_conics");
    expect_size(grad_depths, n, "grad_depths");
    expect_size(grad_means_camera, 3 * n, "grad_means_camera");
    expect_size(grad_rotations_camera, 9 * n, "grad_rotations_camera");
    expect_size(grad_means, 3 * n, "grad_means");
    expect_size(grad_scales, 3 * n, "grad_scales");
    expect_size(grad_quats, 4 * n, "grad_quats");
    expect_size(grad_world_to_camera, 16, "grad_world_to_camera");
    expect_size(grad_intrinsics, 4, "grad_intrinsics");
    nb::gil_scoped_release unlocked;
    surgsplat::project_backward(means.data(), scales.data(), quats.data(), n, camera,
                                grad_means2d.data(), grad_conics.data(), grad_depths.data(),
                                grad_means_camera.data(), grad_rotations_camera.data(),
                                grad_means.data(), grad_scales.data(), grad_quats.data(),
                                grad_world_to_camera.data(), grad_intrinsics.data());
}

}  // namespace

static void bind_project(nb::module_& m) {
    m.def("project_forward", &forward, "EWA projection of 3D Gaussians (see project.py).");
    m.def("project_backward", &backward,
          "Gradients of the projection's inputs: the Gaussians', world_to_camera [4, 4] and the "
          "intrinsics (fx, fy, cx, cy).");
}

static const OpBinding binding(&bind_project);

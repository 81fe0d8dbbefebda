"""EWA projection: closed-form cases, culling, float64 gradcheck of the reference, and the native
kernel against the reference (forward outputs and gradients)."""

import pytest
import torch

from surgsplat.render.native import native_module, set_threads
from surgsplat.image.pinhole import pixel_rays
from surgsplat.render.project import project, project_reference

K = torch.tensor([[100.0, 0, 32.0], [0, 100.0, 24.0], [0, 0, 1]], dtype=torch.float64)


def test_isotropic_gaussian_on_axis():
    sigma, depth = 0.05, 2.0
    proj = project(torch.tensor([[0.0, 0.0, depth]], dtype=torch.float64),
                   torch.full((1, 3), sigma, dtype=torch.float64),
                   torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64), K, 64, 48)
    variance = (sigma * 100.0 / depth) ** 2 + 0.3
    torch.testing.assert_close(proj.means2d, torch.tensor([[32.0, 24.0]], dtype=torch.float64))
    torch.testing.assert_close(proj.conics, torch.tensor([[1 / variance, 0, 1 / variance]],
                                                         dtype=torch.float64))
    assert proj.radii.item() == int(torch.ceil(torch.tensor(3 * variance**0.5)))
    assert proj.depths.item() == depth


def test_culling_behind_camera_and_off_screen():
    means = torch.tensor([[0.0, 0, -1.0], [0.0, 0, 0.005], [50.0, 0, 1.0], [0.0, 0, 1.0]],
                         dtype=torch.float64)
    proj = project(means, torch.full((4, 3), 0.01, dtype=torch.float64),
                   torch.tensor([[1.0, 0, 0, 0]] * 4, dtype=torch.float64), K, 64, 48)
    assert proj.radii.tolist()[:3] == [0, 0, 0]
    assert proj.radii[3] > 0
    assert torch.isfinite(proj.conics).all() and torch.isfinite(proj.means2d).all()


def test_pose_moves_the_camera():
    pose = torch.eye(4, dtype=torch.float64)
    pose[0, 3] = 0.5  # world point (0,0,2) is at x = 0.5 in camera space
    proj = project(torch.tensor([[0.0, 0, 2.0]], dtype=torch.float64),
                   torch.full((1, 3), 0.05, dtype=torch.float64),
                   torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64), K, 64, 48, pose)
    assert proj.means2d[0, 0].item() == pytest.approx(32.0 + 100.0 * 0.5 / 2.0)


def test_project_gradcheck():
    """float64 gradcheck of the reference in the Gaussians and the camera (pose and K), with one
    Gaussian beyond the 1.3x FOV clamp (where the Jacobian's x depends on fx)."""
    generator = torch.Generator().manual_seed(3)
    means = (torch.randn(5, 3, generator=generator, dtype=torch.float64) * 0.2
             + torch.tensor([0, 0, 2.0], dtype=torch.float64))
    means[4, 0] = 3.0  # x / z = 1.5 > 1.3 * 32 / 100
    scales = (torch.rand(5, 3, generator=generator, dtype=torch.float64) * 0.1 + 0.02).requires_grad_()
    quats = torch.randn(5, 4, generator=generator, dtype=torch.float64).requires_grad_()
    pose = torch.eye(4, dtype=torch.float64)
    pose[:3, 3] = torch.tensor([0.05, -0.02, 0.1], dtype=torch.float64)

    def outputs(m, s, q, intrinsics, world_to_camera):
        proj = project(m, s, q, intrinsics, 64, 48, world_to_camera)
        return proj.means2d, proj.conics, proj.depths, proj.rotations_camera

    inputs = (means.requires_grad_(), scales, quats, K.clone().requires_grad_(),
              pose.requires_grad_())
    assert torch.autograd.gradcheck(outputs, inputs, eps=1e-6, atol=1e-5)


def test_ray_directions_through_pixel_centres():
    rays = pixel_rays(K, 64, 48)
    assert rays.shape == (48, 64, 3)
    torch.testing.assert_close(rays[24, 32], torch.tensor([0.005, 0.005, 1.0]))


needs_native = pytest.mark.skipif(native_module() is None, reason="native module not built")
OUTPUTS = ("means2d", "conics", "depths", "means_camera", "rotations_camera")


def native_test_gaussians(num: int, seed: int):
    """float64 Gaussians around a posed camera: most in view, some behind it, beyond the near
    plane, off-screen or outside the 1.3x FOV clamp, with unnormalised quaternions."""
    generator = torch.Generator().manual_seed(seed)
    means = torch.randn(num, 3, generator=generator, dtype=torch.float64) * torch.tensor(
        [1.2, 0.9, 0.8], dtype=torch.float64)
    means[:, 2] += 2.5
    means[:4, 2] = torch.tensor([-1.0, 0.005, 0.5, 3.0], dtype=torch.float64)
    means[3, 0] = 9.0  # far outside the field of view
    scales = torch.rand(num, 3, generator=generator, dtype=torch.float64) * 0.15 + 0.01
    quats = torch.randn(num, 4, generator=generator, dtype=torch.float64) * 2.0
    angle = torch.tensor(0.2, dtype=torch.float64)
    pose = torch.eye(4, dtype=torch.float64)
    pose[:3, :3] = torch.tensor([[torch.cos(angle), 0, torch.sin(angle)], [0, 1, 0],
                                 [-torch.sin(angle), 0, torch.cos(angle)]], dtype=torch.float64)
    pose[:3, 3] = torch.tensor([0.1, -0.05, 0.2], dtype=torch.float64)
    return means, scales, quats, pose


def test_native_projection_forward_matches_reference(native_isa):
    means, scales, quats, pose = native_test_gaussians(4000, seed=5)
    expected = project_reference(means, scales, quats, K, 64, 48, pose, near=0.01, lowpass=0.3)
    # float32 Gaussians with a float64 camera: the Gaussians' dtype selects the kernel.
    native = project(means.float(), scales.float(), quats.float(), K, 64, 48, pose,
                     backend="native")
    culled = expected.radii == 0
    assert 0.1 < float(culled.double().mean()) < 0.9  # both kinds are exercised
    for name in OUTPUTS:
        # float32 against float64: relative to each output's magnitude.
        want, got = getattr(expected, name), getattr(native, name).double()
        assert float((got - want).abs().max() / want.abs().max()) < 1e-5, name
    # The radius is a ceil: float32 rounding may move a value across an integer.
    radius_diff = (native.radii - expected.radii).abs()
    assert int(radius_diff.max()) <= 1 and float((radius_diff > 0).double().mean()) < 0.005


def projection_gradients(means, scales, quats, pose, dtype, backend, seed=7):
    """Gradients of (means, scales, quats, K, pose) of a random linear function of every
    differentiable output of `project` (the same for any dtype and backend)."""
    generator = torch.Generator().manual_seed(seed)
    inputs = [t.to(dtype).requires_grad_() for t in (means, scales, quats, K, pose)]
    proj = project(*inputs[:4], 64, 48, inputs[4], backend=backend)
    outputs = [getattr(proj, name) for name in OUTPUTS]
    upstream = [torch.randn(o.shape, generator=generator, dtype=torch.float64) for o in outputs]
    loss = sum((o * u.to(dtype)).sum() for o, u in zip(outputs, upstream))
    return torch.autograd.grad(loss, inputs)


def test_native_projection_gradients_match_reference(native_isa):
    """float32 native against float64 reference: the Gaussians' gradients within 1e-4 relative
    L2; the camera's, sums over 3000 Gaussians (a third of them culled or clamped), within 1e-5
    of the largest entry; K's unused entries (skew, last row) and the pose's last row get 0."""
    gaussians_and_pose = native_test_gaussians(3000, seed=6)
    want = projection_gradients(*gaussians_and_pose, torch.float64, "reference")
    got = projection_gradients(*gaussians_and_pose, torch.float32, "native")
    for name, w, g in zip(("means", "scales", "quats"), want[:3], got[:3]):
        relative = float((g.double() - w).norm() / w.norm())
        assert relative < 1e-4, f"{name}: relative L2 error {relative:.2e}"
    for name, w, g in zip(("K", "world_to_camera"), want[3:], got[3:]):
        relative = float((g.double() - w).abs().max() / w.abs().max())
        assert relative < 1e-5, f"{name}: max error / max entry {relative:.2e}"
        assert torch.equal(g == 0, w == 0), name


@needs_native
def test_a_camera_that_learns_stays_native_and_sums_deterministically():
    means, scales, quats, pose = native_test_gaussians(5000, seed=1)
    args = (means.float(), scales.float(), quats.float(), K.float(), 64, 48)
    learning = pose.float().requires_grad_()
    with_grad = project(*args, learning)  # auto
    fixed = project(*args, pose.float(), backend="native")
    assert torch.equal(with_grad.means2d.detach(), fixed.means2d)
    assert with_grad.means2d.grad_fn.name().endswith("_NativeProjectBackward")
    threads = torch.get_num_threads()
    grads = []
    try:
        for count in (1, 2, 3):  # blocks of Gaussians summed in order: no dependence on threads
            set_threads(count)
            grads.append(projection_gradients(means, scales, quats, pose, torch.float32,
                                              "native"))
    finally:
        set_threads(threads)
    for other in grads[1:]:
        assert all(torch.equal(a, b) for a, b in zip(grads[0], other))

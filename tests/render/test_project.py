"""EWA projection: closed-form cases, culling, float64 gradcheck of the reference, and the native
kernel against the reference (forward outputs and gradients)."""

import pytest
import torch

from surgsplat.render.native import native_module
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
    generator = torch.Generator().manual_seed(3)
    means = (torch.randn(5, 3, generator=generator, dtype=torch.float64) * 0.2
             + torch.tensor([0, 0, 2.0], dtype=torch.float64)).requires_grad_()
    scales = (torch.rand(5, 3, generator=generator, dtype=torch.float64) * 0.1 + 0.02).requires_grad_()
    quats = torch.randn(5, 4, generator=generator, dtype=torch.float64).requires_grad_()

    def outputs(m, s, q):
        proj = project(m, s, q, K, 64, 48)
        return proj.means2d, proj.conics, proj.depths

    assert torch.autograd.gradcheck(outputs, (means, scales, quats), eps=1e-6, atol=1e-5)


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


@needs_native
def test_native_projection_forward_matches_reference():
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


@needs_native
def test_native_projection_gradients_match_reference():
    means, scales, quats, pose = native_test_gaussians(3000, seed=6)
    generator = torch.Generator().manual_seed(7)
    upstream = None
    grads = {}
    for dtype, backend in ((torch.float64, "reference"), (torch.float32, "native")):
        inputs = [t.to(dtype).requires_grad_() for t in (means, scales, quats)]
        proj = project(*inputs, K.to(dtype), 64, 48, pose.to(dtype), backend=backend)
        outputs = [getattr(proj, name) for name in OUTPUTS]
        if upstream is None:
            upstream = [torch.randn(o.shape, generator=generator, dtype=torch.float64)
                        for o in outputs]
        loss = sum((o * u.to(dtype)).sum() for o, u in zip(outputs, upstream))
        grads[backend] = torch.autograd.grad(loss, inputs)
    for name, want, got in zip(("means", "scales", "quats"), grads["reference"], grads["native"]):
        relative = float((got.double() - want).norm() / want.norm())
        assert relative < 1e-4, f"{name}: relative L2 error {relative:.2e}"


@needs_native
def test_native_projection_only_for_a_fixed_camera():
    means, scales, quats, pose = native_test_gaussians(8, seed=1)
    pose = pose.float().requires_grad_()
    args = (means.float(), scales.float(), quats.float(), K.float(), 64, 48, pose)
    project(*args).means2d.sum().backward()  # auto: the reference, gradients reach the pose
    assert pose.grad is not None and pose.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="camera without gradients"):
        project(*args, backend="native")

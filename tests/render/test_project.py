"""EWA projection: closed-form cases, culling, and float64 gradcheck."""

import pytest
import torch

from surgsplat.render.project import camera_ray_directions, project

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
    rays = camera_ray_directions(K, 64, 48)
    assert rays.shape == (48, 64, 3)
    torch.testing.assert_close(rays[24, 32], torch.tensor([0.005, 0.005, 1.0]))

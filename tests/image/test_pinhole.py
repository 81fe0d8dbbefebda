"""Pixel rays, back-projection, and normals of the surface a depth map describes."""

import math

import torch

from surgsplat.image.depth import depth_gradient_magnitude
from surgsplat.image.pinhole import backproject_camera, depth_normals, pixel_rays

H, W, FOCAL = 32, 40, 40.0
K = torch.tensor([[FOCAL, 0, W / 2 + 3.0], [0, FOCAL * 1.1, H / 2 - 2.0], [0, 0, 1.0]])


def test_pixel_rays_go_through_pixel_centres():
    rays = pixel_rays(K, W, H)
    assert rays.shape == (H, W, 3)
    # the pixel whose centre is (cx + 0.5, cy + 0.5) has ray (0.5 / fx, 0.5 / fy, 1)
    u, v = int(K[0, 2]), int(K[1, 2])
    assert torch.allclose(rays[v, u], torch.tensor([0.5 / FOCAL, 0.5 / (1.1 * FOCAL), 1.0]))


def plane_depth(normal: torch.Tensor, offset: float) -> torch.Tensor:
    """z-depth [H, W] of the plane n . X = offset along every pixel ray (float64)."""
    rays = pixel_rays(K, W, H, torch.float64)
    return offset / (rays @ normal)


def test_depth_normals_of_a_tilted_plane_are_exact():
    angle = 0.6
    normal = torch.tensor([math.sin(angle), 0.2, math.cos(angle)], dtype=torch.float64)
    normal = normal / normal.norm()
    depth = plane_depth(normal, 60.0)
    normals, valid = depth_normals(depth, K.double())
    assert valid[1:-1, 1:-1].all() and not valid[0].any() and not valid[:, -1].any()
    error = (normals[valid] - normal).abs().max()
    assert error < 1e-9  # a plane's finite differences are exact
    points = backproject_camera(depth, K.double())
    assert torch.allclose(points @ normal, torch.full((H, W), 60.0, dtype=torch.float64))


def test_depth_normals_skip_missing_depth():
    depth = plane_depth(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), 50.0)
    depth[10, 10] = 0.0
    _, valid = depth_normals(depth, K.double())
    assert not valid[9:12, 10].any() and not valid[10, 9:12].any() and valid[5, 5]


def test_depth_gradient_of_a_ramp():
    depth = torch.arange(W, dtype=torch.float64).repeat(H, 1) * 0.5 + 10.0
    assert torch.allclose(depth_gradient_magnitude(depth), torch.full((H, W), 0.5,
                                                                      dtype=torch.float64))


def reference_depth_normals(depth: torch.Tensor) -> torch.Tensor:
    """The plain formulation: torch.linalg.cross of the back-projected neighbours' differences,
    turned to face away from the camera; interior pixels only [H-2, W-2, 3]."""
    points = backproject_camera(depth, K.to(depth.dtype))
    cross = torch.linalg.cross(points[1:-1, 2:] - points[1:-1, :-2],
                               points[2:, 1:-1] - points[:-2, 1:-1], dim=-1)
    normal = cross / cross.norm(dim=-1, keepdim=True)
    facing = (normal * points[1:-1, 1:-1]).sum(-1, keepdim=True)
    return torch.where(facing < 0, -normal, normal)


def test_depth_normals_match_the_cross_product_reference_with_gradients():
    """A bumpy surface in float64: normals within 1e-12 and the gradient of a random projection
    of them within 1e-9 (relative to its largest entry) of the plain cross-product version."""
    generator = torch.Generator().manual_seed(0)
    depth = (60.0 + torch.rand(H, W, generator=generator, dtype=torch.float64)).requires_grad_()
    weights = torch.randn(H - 2, W - 2, 3, generator=generator, dtype=torch.float64)
    normals, valid = depth_normals(depth, K.double())
    assert valid[1:-1, 1:-1].all()
    expected = reference_depth_normals(depth)
    torch.testing.assert_close(normals[1:-1, 1:-1], expected, atol=1e-12, rtol=0)
    (gradient,) = torch.autograd.grad((normals[1:-1, 1:-1] * weights).sum(), depth)
    (reference,) = torch.autograd.grad((expected * weights).sum(), depth)
    scale = float(reference.abs().max())
    torch.testing.assert_close(gradient, reference, atol=1e-9 * scale, rtol=0)


def test_depth_normals_give_finite_gradients_where_nothing_is_rendered():
    """A rendered depth is 0 where no Gaussian covers the image (a moving camera turning toward
    tissue not yet reconstructed). The normal there is invalid and must not turn the gradient
    of a loss over the valid pixels into NaN (the sqrt of a zero cross product did, and
    `endoplanar` stopped on the moving phantom once its normal loss started)."""
    K = torch.tensor([[50.0, 0, 16], [0, 50.0, 12], [0, 0, 1]])
    depth = torch.full((24, 32), 80.0)
    depth[:, :10] = 0.0  # uncovered strip
    depth = depth.requires_grad_()
    normals, valid = depth_normals(depth, K)
    target = torch.tensor([0.0, 0.0, 1.0])
    error = (normals - target).abs().sum(-1)
    loss = torch.where(valid, error, torch.zeros_like(error)).sum()
    loss.backward()
    assert valid[:, :11].sum() == 0 and valid[1:-1, 12:-1].all()
    assert torch.isfinite(depth.grad).all()

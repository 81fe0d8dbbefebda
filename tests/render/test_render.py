"""render(): colour channels, SH, background, extras, and EndoPlanar's unbiased plane depth."""

import math

import pytest
import torch

from surgsplat.image.pinhole import pixel_rays
from surgsplat.render.native import native_module
from surgsplat.methods.endoplanar.plane_depth import planar_normals_and_distances, unbiased_plane_depth
from surgsplat.render.render import MIN_ALPHA_FOR_DEPTH, _SplitChannels, render
from surgsplat.render.sh import SH_C0, eval_sh, sh_colour

W, H = 48, 40
K = torch.tensor([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])


def tilted_plane(angle: float, distance: float = 3.0, spacing: float = 0.05):
    """Flattened Gaussians tiling the plane n . X = distance cos(angle), n = (sin a, 0, cos a)."""
    xs = torch.arange(-2.5, 2.5, spacing)
    x, y = torch.meshgrid(xs, xs, indexing="ij")
    x, y = x.reshape(-1), y.reshape(-1)
    z = (distance * math.cos(angle) - x * math.sin(angle)) / math.cos(angle)
    means = torch.stack([x, y, z], dim=1)
    n = means.shape[0]
    scales = torch.tensor([spacing, spacing, 1e-6]).repeat(n, 1)
    quats = torch.tensor([math.cos(angle / 2), 0, math.sin(angle / 2), 0]).repeat(n, 1)
    normal = torch.tensor([math.sin(angle), 0.0, math.cos(angle)])
    return means, scales, quats, normal, distance * math.cos(angle)


@pytest.mark.parametrize("backend", ["native", "reference"])
def test_plane_depth_is_the_ray_plane_intersection(backend):
    means, scales, quats, normal, offset = tilted_plane(0.5)
    normals, distances = planar_normals_and_distances(means, scales, quats, torch.eye(4))
    out = render(means, scales, quats, torch.full((means.shape[0],), 0.9),
                 torch.rand(means.shape[0], 3), K, W, H, backend=backend,
                 extras={"normal": normals, "plane_distance": distances})
    plane_depth = unbiased_plane_depth(out.extras["normal"], out.extras["plane_distance"][..., 0], K)
    rays = pixel_rays(K, W, H)
    truth = offset / (rays @ normal)
    covered = out.alpha > 0.99
    assert covered.float().mean() > 0.9
    relative = ((plane_depth - truth).abs() / truth)[covered]
    assert relative.max() < 1e-3
    unit = torch.nn.functional.normalize(out.extras["normal"][covered], dim=-1)
    assert (unit @ normal).min() > 0.999  # faces away from the camera, as EndoPlanar defines


def test_constant_colour_background_and_depth():
    means, scales, quats, _, _ = tilted_plane(0.0)
    n = means.shape[0]
    colour = torch.tensor([0.2, 0.5, 0.7])
    out = render(means, scales, quats, torch.full((n,), 0.9), colour.repeat(n, 1), K, W, H,
                 background=torch.tensor([1.0, 0.0, 0.0]))
    covered = out.alpha > 0.999
    torch.testing.assert_close(out.rgb[covered], colour.expand(int(covered.sum()), 3),
                               atol=2e-3, rtol=0)
    torch.testing.assert_close(out.depth[covered], torch.full((int(covered.sum()),), 3.0),
                               atol=1e-4, rtol=0)


def test_sh_degree_zero_is_the_dc_colour():
    dirs = torch.nn.functional.normalize(torch.randn(10, 3), dim=-1)
    coeffs = torch.randn(10, 4, 3)
    torch.testing.assert_close(eval_sh(0, coeffs, dirs), (SH_C0 * coeffs[:, 0] + 0.5).clamp_min(0))
    assert not torch.allclose(eval_sh(1, coeffs, dirs), eval_sh(0, coeffs, dirs))
    with pytest.raises(ValueError, match="degree"):
        eval_sh(4, coeffs, dirs)


def test_extras_are_blended_like_colour():
    means, scales, quats, _, _ = tilted_plane(0.2)
    n = means.shape[0]
    colors = torch.rand(n, 3)
    out = render(means, scales, quats, torch.full((n,), 0.8), colors, K, W, H,
                 extras={"logit": colors[:, 0], "pair": colors[:, 1:]})
    torch.testing.assert_close(out.extras["logit"][..., 0], out.rgb[..., 0])
    torch.testing.assert_close(out.extras["pair"], out.rgb[..., 1:])


def test_split_channel_gradients_match_autograds_composition():
    """The written-out backward of the colour view, the depth normalisation and the extra
    channels' views equals autograd's gradient of the same expression (float64, 1e-12),
    including pixels whose alpha is below the depth clamp, and whichever outputs are used."""
    generator = torch.Generator().manual_seed(3)
    sizes = (3, 1, 2)
    image = torch.rand(7, 5, 4 + sum(sizes), generator=generator, dtype=torch.float64)
    alpha = torch.rand(7, 5, generator=generator, dtype=torch.float64)
    alpha[0, :3] = MIN_ALPHA_FOR_DEPTH / 2  # clamped: no depth gradient to alpha
    upstream = [torch.randn(7, 5, 3, generator=generator, dtype=torch.float64),
                torch.randn(7, 5, generator=generator, dtype=torch.float64),
                *(torch.randn(7, 5, k, generator=generator, dtype=torch.float64)
                  for k in sizes)]

    def composed(i, a, sizes):
        return (i[..., :3], i[..., 3] / a.clamp_min(MIN_ALPHA_FOR_DEPTH), i[..., 4:7],
                i[..., 7:8], i[..., 8:10])

    for used in ((0, 1, 2, 3, 4), (0,), (1,), (2, 4), (0, 3)):
        grads = []
        for fn in (_SplitChannels.apply, composed):
            i, a = image.clone().requires_grad_(), alpha.clone().requires_grad_()
            outputs = fn(i, a, sizes)
            sum((outputs[k] * upstream[k]).sum() for k in used).backward()
            grads.append((i.grad, torch.zeros_like(a) if a.grad is None else a.grad))
        (i_fused, a_fused), (i_auto, a_auto) = grads
        assert torch.allclose(i_fused, i_auto, atol=1e-12, rtol=0), used
        assert torch.allclose(a_fused, a_auto, atol=1e-12, rtol=0), used


needs_native = pytest.mark.skipif(native_module() is None, reason="native module not built")


def sh_inputs(num: int, coeffs: int, seed: int):
    """Coefficients ~N(0, 1.5) (so some colours clamp at 0), means around a camera 4 units
    away."""
    generator = torch.Generator().manual_seed(seed)
    sh = torch.randn(num, coeffs, 3, generator=generator) * 1.5
    means = torch.randn(num, 3, generator=generator) * 2.0
    world_to_camera = torch.eye(4)
    world_to_camera[:3, :3] = torch.linalg.qr(torch.randn(3, 3, generator=generator))[0]
    world_to_camera[:3, 3] = torch.tensor([0.3, -0.2, 4.0])
    return sh, means, world_to_camera


@pytest.mark.parametrize("degree, coeffs", [(0, 1), (1, 4), (1, 9), (2, 9), (3, 16)])
def test_native_sh_colour_matches_reference(native_isa, degree, coeffs):
    sh, means, world_to_camera = sh_inputs(500, coeffs, seed=degree)
    upstream = torch.randn(500, 3, generator=torch.Generator().manual_seed(3))

    def colour_and_grads(backend, dtype):
        leaves = [x.to(dtype).requires_grad_(True) for x in (sh, means, world_to_camera)]
        rgb = sh_colour(degree, *leaves, backend=backend)
        grads = torch.autograd.grad((rgb * upstream.to(dtype)).sum(), leaves, allow_unused=True)
        return rgb.detach(), [torch.zeros_like(x) if g is None else g
                              for x, g in zip(leaves, grads)]

    rgb, (grad_sh, grad_means, grad_pose) = colour_and_grads("native", torch.float32)
    expected, (expected_sh, expected_means, expected_pose) = colour_and_grads("reference",
                                                                              torch.float64)
    assert (rgb == 0).any() and (rgb > 0).any()  # both sides of the clamp are exercised
    assert float((rgb.double() - expected).abs().max()) < 4e-6  # colours up to ~8, float32
    # gradients: max abs error relative to the largest reference entry (float32 rounding)
    assert float((grad_sh.double() - expected_sh).abs().max()) < 1e-6 * float(
        expected_sh.abs().max())
    assert not grad_sh[:, (degree + 1) ** 2:].any()  # unused coefficients get none
    scale = max(float(expected_means.abs().max()), 1.0)
    assert float((grad_means.double() - expected_means).abs().max()) < 1e-5 * scale
    # the camera (through its centre): a sum over 500 Gaussians, float32 against float64
    scale = max(float(expected_pose.abs().max()), 1.0)
    assert float((grad_pose.double() - expected_pose).abs().max()) < 1e-5 * scale


@needs_native
def test_sh_colour_with_a_camera_that_learns_stays_native():
    sh, means, world_to_camera = sh_inputs(50, 4, seed=5)
    pose = world_to_camera.clone().requires_grad_(True)
    rgb = sh_colour(1, sh, means, pose)
    rgb.sum().backward()
    assert pose.grad is not None and pose.grad.abs().sum() > 0
    assert torch.equal(rgb.detach(), sh_colour(1, sh, means, world_to_camera, backend="native"))
    with pytest.raises(ValueError, match="K >= 9"):
        sh_colour(2, sh, means, world_to_camera)

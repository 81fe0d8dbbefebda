"""The rasterizer contract: reference gradcheck, native == reference (forward, gradients,
absolute screen gradient), edge cases, and input validation.

Tolerances: float32 forward max abs difference 1e-5; gradients relative L2 error 1e-4."""

import pytest
import torch

from surgsplat.render import native as native_loader
from surgsplat.render.native import resolve_backend
from surgsplat.render.pixel_weights import PixelWeights
from surgsplat.render.rasterize import rasterize
from surgsplat.render.reference import rasterize_reference

needs_native = pytest.mark.skipif(native_loader.native_module() is None,
                                  reason="native module not built")
DIFFERENTIABLE = ("means2d", "conics", "opacities", "features")


def run(scene, backend, grad_seed=1, background=None, weights=None, pixel_weights=None):
    """Forward and backward with a fixed random upstream gradient (times `pixel_weights` [H, W]
    when given), with the gradient weights `weights` (PixelWeights) when given."""
    leaves = {k: scene[k].detach().clone().requires_grad_() for k in DIFFERENTIABLE}
    absgrad = torch.zeros(scene["means2d"].shape[0], dtype=scene["means2d"].dtype)
    image, alpha = rasterize(leaves["means2d"], leaves["conics"], leaves["opacities"],
                             leaves["features"], scene["depths"], scene["radii"],
                             scene["width"], scene["height"], absgrad=absgrad,
                             background=background, gradient_weights=weights, backend=backend)
    generator = torch.Generator().manual_seed(grad_seed)
    grad_image = torch.randn(image.shape, generator=generator, dtype=image.dtype)
    grad_alpha = torch.randn(alpha.shape, generator=generator, dtype=alpha.dtype)
    if pixel_weights is not None:
        grad_image, grad_alpha = grad_image * pixel_weights[..., None], grad_alpha * pixel_weights
    if image.requires_grad:
        ((image * grad_image).sum() + (alpha * grad_alpha).sum()).backward()
    grads = {k: v.grad if v.grad is not None else torch.zeros_like(v) for k, v in leaves.items()}
    return image.detach(), alpha.detach(), grads, absgrad


def relative_error(a, b):
    return float((a - b).norm() / b.norm().clamp_min(1e-12))


def test_reference_gradcheck(scene_factory):
    scene = scene_factory(6, 9, 7, channels=2, dtype=torch.float64, scale=0.3)
    inputs = tuple(scene[k].clone().requires_grad_() for k in DIFFERENTIABLE)

    def composite(m, c, o, f):
        return rasterize_reference(m, c, o, f, scene["depths"], scene["radii"], 9, 7)

    assert torch.autograd.gradcheck(composite, inputs, eps=1e-6, atol=1e-6)


@pytest.mark.parametrize("num,width,height,channels", [
    (300, 37, 29, 3), (200, 16, 16, 1), (150, 33, 20, 32), (400, 48, 40, 8)])
def test_native_matches_reference(native_isa, scene_factory, num, width, height, channels):
    scene = scene_factory(num, width, height, channels=channels, seed=num)
    native = run(scene, "native")
    reference = run(scene, "reference")
    assert (native[0] - reference[0]).abs().max() < 1e-5
    assert (native[1] - reference[1]).abs().max() < 1e-5
    for name in DIFFERENTIABLE:
        assert relative_error(native[2][name], reference[2][name]) < 1e-4, name
    assert relative_error(native[3], reference[3]) < 1e-4


def test_opaque_layers_stop_early_in_both(native_isa, scene_factory):
    scene = scene_factory(500, 24, 24, seed=7, scale=0.4)
    scene["opacities"] = torch.full_like(scene["opacities"], 0.98)
    native, reference = run(scene, "native"), run(scene, "reference")
    assert (native[0] - reference[0]).abs().max() < 1e-5
    assert (native[1] > 0.999).float().mean() > 0.5  # most pixels reached the stop
    for name in DIFFERENTIABLE:
        assert relative_error(native[2][name], reference[2][name]) < 1e-4, name


def diagonal_needles(num: int, width: int, height: int, seed: int = 0) -> dict:
    """Long thin Gaussians along the image diagonals, centred near tile corners: their alpha
    boxes touch tiles (the off-diagonal corners of the boxes) that their ellipses miss."""
    generator = torch.Generator().manual_seed(seed)
    corners = torch.tensor([[16.0 * (1 + i % 3), 16.0 * (1 + i // 3 % 2)] for i in range(num)])
    means2d = corners + torch.rand(num, 2, generator=generator) * 2.0 - 1.0
    angles = torch.where(torch.arange(num) % 2 == 0, 0.785, -0.785)
    axis = torch.stack([angles.cos(), angles.sin()], -1)  # [N, 2]
    normal = torch.stack([-axis[:, 1], axis[:, 0]], -1)
    # conic = R diag(1 / 9^2, 1 / 0.7^2) R^T: 9 px along the axis, 0.7 px across
    conic = (axis[:, :, None] * axis[:, None, :] / 81.0
             + normal[:, :, None] * normal[:, None, :] / 0.49)
    return {"means2d": means2d, "conics": torch.stack([conic[:, 0, 0], conic[:, 0, 1],
                                                       conic[:, 1, 1]], -1),
            "opacities": torch.rand(num, generator=generator) * 0.5 + 0.45,
            "features": torch.rand(num, 3, generator=generator),
            "depths": torch.rand(num, generator=generator) + 1.0,
            "radii": torch.full((num,), 30, dtype=torch.int32), "width": width, "height": height}


def test_tiles_an_ellipse_misses_are_not_binned_and_change_nothing(native_isa):
    scene = diagonal_needles(12, 64, 48)
    module = native_loader.native_module()
    bins = module.rasterize_forward(
        *(scene[k].contiguous().numpy() for k in (*DIFFERENTIABLE, "depths", "radii")),
        torch.zeros(3).numpy(), 64, 48, torch.empty(48, 64, 3).numpy(),
        torch.empty(48, 64).numpy(), torch.empty(48, 64, dtype=torch.int32).numpy())
    assert bins.num_overlaps < bins.box_overlaps
    native, reference = run(scene, "native"), run(scene, "reference")
    assert (native[0] - reference[0]).abs().max() < 1e-5
    assert (native[1] - reference[1]).abs().max() < 1e-5
    for name in DIFFERENTIABLE:
        assert relative_error(native[2][name], reference[2][name]) < 1e-4, name
    assert relative_error(native[3], reference[3]) < 1e-4


@pytest.mark.parametrize("num,opacity,seed", [(300, None, 11), (500, 0.98, 12), (40, None, 13)])
def test_background_matches_reference(native_isa, scene_factory, num, opacity, seed):
    """A background [C] seen through the remaining transmittance: native == reference in the
    image and in every gradient (through alpha), for sparse scenes where most of it shows, and
    for opaque ones where compositing stops early; a zero background changes nothing."""
    scene = scene_factory(num, 37, 29, channels=4, seed=seed, scale=0.4 if opacity else 0.12)
    if opacity is not None:
        scene["opacities"] = torch.full_like(scene["opacities"], opacity)
    background = torch.tensor([0.9, -0.4, 0.3, 2.0])
    native = run(scene, "native", background=background)
    reference = run(scene, "reference", background=background)
    assert (native[0] - reference[0]).abs().max() < 1e-5
    for name in DIFFERENTIABLE:
        assert relative_error(native[2][name], reference[2][name]) < 1e-4, name
    assert relative_error(native[3], reference[3]) < 1e-4
    plain, black = run(scene, "native"), run(scene, "native", background=torch.zeros(4))
    assert torch.equal(plain[0], black[0])
    assert (native[0] - plain[0]).abs().max() > 0.1  # the background shows
    for name in DIFFERENTIABLE:
        assert torch.equal(plain[2][name], black[2][name]), name


def random_weights(scene, seed, binary):
    """Gradient weights of about half the Gaussians: 0 on a disc of about a third of the pixels
    and 1 elsewhere (binary, a gate), or uniform in [0, 1] on every pixel."""
    generator = torch.Generator().manual_seed(seed)
    members = torch.rand(scene["means2d"].shape[0], generator=generator) < 0.5
    if not binary:
        shape = (scene["height"], scene["width"])
        return PixelWeights(torch.rand(shape, generator=generator), members)
    y, x = torch.meshgrid(torch.arange(scene["height"]), torch.arange(scene["width"]),
                          indexing="ij")
    centre_x, centre_y = scene["width"] * 0.4, scene["height"] * 0.6
    disc = (x - centre_x) ** 2 + (y - centre_y) ** 2 < 0.1 * scene["width"] * scene["height"]
    return PixelWeights((~disc).float(), members)


@pytest.mark.parametrize("binary", [True, False], ids=["gate", "continuous"])
@pytest.mark.parametrize("num,width,height,channels", [(300, 37, 29, 3), (400, 48, 40, 9)])
def test_weighted_gradients_match_reference(native_isa, scene_factory, num, width, height,
                                            channels, binary):
    """With PixelWeights: native == reference in every gradient and absgrad (forward unchanged);
    in both, a member's gradient is that of the loss with each pixel's term weighted by its
    weight, and every other Gaussian's is that of the whole loss, each to 1e-4 relative L2
    (float32)."""
    scene = scene_factory(num, width, height, channels=channels, seed=num, scale=0.3)
    weights = random_weights(scene, num, binary)
    background = torch.linspace(0.2, 0.9, channels)
    native = run(scene, "native", weights=weights, background=background)
    reference = run(scene, "reference", weights=weights, background=background)
    plain = run(scene, "native", background=background)
    assert torch.equal(native[0], plain[0]) and torch.equal(native[1], plain[1])
    for name in DIFFERENTIABLE:
        assert relative_error(native[2][name], reference[2][name]) < 1e-4, name
    assert relative_error(native[3], reference[3]) < 1e-4
    weighted_loss = run(scene, "native", background=background, pixel_weights=weights.weights)
    members = weights.members
    for name in DIFFERENTIABLE:
        weighted = native[2][name]
        assert relative_error(weighted[members], weighted_loss[2][name][members]) < 1e-4, name
        assert relative_error(weighted[~members], plain[2][name][~members]) < 1e-4, name
        # the weights matter: the members' gradients differ from the unweighted ones
        assert relative_error(weighted[members], plain[2][name][members]) > 0.05, name


def test_gradient_weights_are_checked(scene_factory):
    scene = scene_factory(10, 16, 16)
    members = torch.zeros(10, dtype=torch.bool)
    with pytest.raises(ValueError, match="gradient weights must be"):
        run(scene, "auto", weights=PixelWeights(torch.ones(16, 15), members))
    with pytest.raises(ValueError, match="must be float and their members bool"):
        run(scene, "auto", weights=PixelWeights(torch.ones(16, 16), members.float()))
    with pytest.raises(ValueError, match=r"must lie in \[0, 1\]"):
        run(scene, "auto", weights=PixelWeights(torch.full((16, 16), 1.5), members))


def test_background_shape_is_checked(scene_factory):
    scene = scene_factory(10, 16, 16)
    with pytest.raises(ValueError, match="background must be"):
        run(scene, "auto", background=torch.zeros(4))


@pytest.mark.parametrize("backend", ["reference", pytest.param("native", marks=needs_native)])
class TestEdgeCases:
    def test_empty_scene(self, backend, scene_factory):
        scene = scene_factory(0, 20, 10)
        image, alpha, grads, _ = run(scene, backend)
        assert image.shape == (10, 20, 3) and not image.any() and not alpha.any()

    def test_everything_culled(self, backend, scene_factory):
        scene = scene_factory(50, 20, 10)
        scene["radii"] = torch.zeros_like(scene["radii"])
        image, alpha, grads, absgrad = run(scene, backend)
        assert not image.any() and not alpha.any()
        assert not any(g.any() for g in grads.values()) and not absgrad.any()

    def test_one_gaussian_covering_the_image(self, backend):
        scene = {"means2d": torch.tensor([[10.0, 8.0]]), "conics": torch.tensor([[1e-7, 0, 1e-7]]),
                 "opacities": torch.tensor([0.5]), "features": torch.tensor([[0.2, 0.4, 0.6]]),
                 "depths": torch.tensor([1.0]), "radii": torch.tensor([1000], dtype=torch.int32),
                 "width": 21, "height": 17}
        image, alpha, grads, _ = run(scene, backend)
        assert torch.allclose(alpha, torch.full_like(alpha, 0.5), atol=1e-3)
        assert torch.allclose(image[..., 2], torch.full_like(alpha, 0.3), atol=1e-3)

    def test_sub_pixel_and_zero_opacity(self, backend, scene_factory):
        scene = scene_factory(40, 30, 20)
        scene["conics"] = torch.tensor([[25.0, 0.0, 25.0]]).repeat(40, 1)  # sigma 0.2 px
        scene["opacities"][::2] = 0.0
        image, alpha, grads, _ = run(scene, backend)
        assert torch.isfinite(image).all() and alpha.max() <= 0.99 + 1e-6
        assert not grads["features"][::2].any()  # zero opacity: no contribution, no gradient

    @pytest.mark.parametrize("size", [(1, 1), (17, 33), (5, 40)])
    def test_odd_image_sizes(self, backend, scene_factory, size):
        scene = scene_factory(30, *size)
        image, alpha, _, _ = run(scene, backend)
        assert image.shape == (size[1], size[0], 3) and alpha.shape == (size[1], size[0])


@pytest.mark.parametrize("size", [(1, 1), (17, 33), (5, 40)])
def test_odd_image_sizes_agree(native_isa, scene_factory, size):
    scene = scene_factory(60, *size, seed=5)
    native, reference = run(scene, "native"), run(scene, "reference")
    assert (native[0] - reference[0]).abs().max() < 1e-5


@pytest.mark.parametrize("name", ["means2d", "conics", "opacities", "features"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_input_is_rejected(scene_factory, name, bad):
    scene = scene_factory(10, 16, 16)
    drawn = int(torch.nonzero(scene["radii"] > 0)[0])
    scene[name] = scene[name].clone()
    scene[name][drawn] = bad
    with pytest.raises(ValueError, match=f"{name} has 1 non-finite|{name} has [0-9]+ non-finite"):
        run(scene, "auto")


def test_feature_shape_is_checked(scene_factory):
    scene = scene_factory(10, 16, 16)
    scene["features"] = scene["features"][:5]
    with pytest.raises(ValueError, match="features must be"):
        run(scene, "auto")


def test_missing_native_module_falls_back_with_one_warning(monkeypatch):
    import sys

    import surgsplat.render
    native_loader.native_module.cache_clear()
    native_loader._portable.cache_clear()
    native_loader.isa_unavailable.cache_clear()
    for isa in native_loader.ISAS:
        monkeypatch.setitem(sys.modules, f"surgsplat.render._native_{isa}", None)
        monkeypatch.delattr(surgsplat.render, f"_native_{isa}", raising=False)
    try:
        with pytest.warns(RuntimeWarning, match="PyTorch reference"):
            assert resolve_backend("rasterize", "auto", [torch.zeros(1)]) == "reference"
        with pytest.raises(RuntimeError, match="not built"):
            resolve_backend("rasterize", "native", [torch.zeros(1)])
    finally:
        monkeypatch.undo()
        for cached in (native_loader.native_module, native_loader._portable,
                       native_loader.isa_unavailable):
            cached.cache_clear()

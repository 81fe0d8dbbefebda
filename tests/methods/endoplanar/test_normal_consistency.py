"""EndoPlanar's normal consistency: the native kernels against the PyTorch composition (values,
counts and gradients, per ISA variant), what is counted, and the boundary's errors."""

import math

import pytest
import torch

from surgsplat.methods.endoplanar.normal_consistency import (normal_consistency,
                                                normal_consistency_reference)
from surgsplat.image.pinhole import pixel_rays
from surgsplat.render.native import native_module

needs_native = pytest.mark.skipif(
    native_module() is None or not hasattr(native_module(), "normal_consistency_forward"),
    reason="native module not built")


def intrinsics(height: int, width: int) -> torch.Tensor:
    return torch.tensor([[0.9 * width, 0, width / 2 + 1.5], [0, width, height / 2 - 1.0],
                         [0, 0, 1.0]])


def maps(height: int, width: int, seed: int = 0):
    """A wavy surface's depth [H, W] (mm, with holes of no depth), rendered normals [H, W, 3]
    near it and of all lengths (one near zero), a mask and weights."""
    generator = torch.Generator().manual_seed(seed)
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float32),
                          torch.arange(width, dtype=torch.float32), indexing="ij")
    depth = 60 + 4 * torch.sin(u / 5) + 3 * torch.cos(v / 4) + 0.2 * torch.rand(
        height, width, generator=generator)
    depth[torch.rand(height, width, generator=generator) < 0.05] = 0.0
    normals = torch.randn(height, width, 3, generator=generator) * 0.4 + torch.tensor(
        [0.0, 0.0, 1.0])
    normals = normals * (0.1 + 2 * torch.rand(height, width, 1, generator=generator))
    normals[height // 2, width // 2] = 1e-14
    mask = torch.rand(height, width, generator=generator) < 0.8
    weights = torch.rand(height, width, generator=generator)
    return depth, normals, mask, weights


@needs_native
@pytest.mark.parametrize("height,width", [(1, 1), (2, 5), (3, 3), (37, 45), (64, 20)])
@pytest.mark.parametrize("weighted", [False, True])
def test_native_matches_reference_value_count_and_gradients(native_isa, height, width,
                                                            weighted):
    """float32 native kernels against the float64 reference: the sum within 1e-5 relative, the
    count exactly, both gradients within 1e-4 of the largest entry."""
    depth, normals, mask, weights = maps(height, width)
    K = intrinsics(height, width)
    weights = weights if weighted else None
    inputs = [t.clone().requires_grad_() for t in (depth, normals)]
    reference = [t.double().requires_grad_() for t in (depth, normals)]
    total, count = normal_consistency(*inputs, K, mask, weights, backend="native")
    expected, expected_count = normal_consistency_reference(
        *reference, K.double(), mask, None if weights is None else weights.double())
    assert type(total.grad_fn).__name__ == "_NativeNormalConsistencyBackward"
    assert int(count) == int(expected_count)
    assert abs(total.item() - expected.item()) <= 1e-5 * max(abs(expected.item()), 1.0)
    if int(count) == 0:
        assert total.item() == 0.0
        return
    (2.5 * total).backward()
    (2.5 * expected).backward()
    for got, want in zip(inputs, reference):
        scale = want.grad.abs().max().item()
        assert scale > 0
        assert (got.grad.double() - want.grad).abs().max().item() < 1e-4 * max(scale, 1.0)


@needs_native
def test_native_computes_only_the_gradient_asked_for(native_isa):
    depth, normals, mask, weights = maps(30, 40, seed=3)
    K = intrinsics(30, 40)
    both = [t.clone().requires_grad_() for t in (depth, normals)]
    normal_consistency(*both, K, mask, weights, backend="native")[0].backward()
    for index in range(2):
        one = [t.clone().requires_grad_(i == index) for i, t in enumerate((depth, normals))]
        normal_consistency(*one, K, mask, weights, backend="native")[0].backward()
        assert torch.equal(one[index].grad, both[index].grad)
        assert one[1 - index].grad is None


@pytest.mark.parametrize("backend", ["reference", "auto"])
def test_a_plane_rendered_with_its_own_normals_is_consistent(backend):
    """Depth and normals of one tilted plane: every interior pixel counts and the sum is ~0;
    flipping the rendered normals costs 2 x |n|_1 per pixel."""
    height, width = 24, 32
    K = intrinsics(height, width)
    normal = torch.tensor([math.sin(0.5), 0.3, math.cos(0.5)])
    normal = normal / normal.norm()
    depth = 70.0 / (pixel_rays(K, width, height) @ normal)
    rendered = normal.expand(height, width, 3).clone()
    mask = torch.ones(height, width, dtype=torch.bool)
    total, count = normal_consistency(depth, rendered, K, mask, backend=backend)
    assert int(count) == (height - 2) * (width - 2)
    assert total.item() < 1e-3 * int(count)
    flipped, _ = normal_consistency(depth, -rendered, K, mask, backend=backend)
    assert flipped.item() == pytest.approx(2 * normal.abs().sum().item() * int(count), rel=1e-3)


def test_k_with_a_gradient_takes_the_reference():
    depth, normals, mask, weights = maps(12, 14)
    K = intrinsics(12, 14).requires_grad_()
    total, _ = normal_consistency(depth, normals.requires_grad_(), K, mask, weights)
    total.backward()
    assert K.grad is not None and K.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="K no gradient"):
        normal_consistency(depth, normals, K, mask, weights, backend="native")


@pytest.mark.parametrize("change,message", [
    ({"normals": torch.zeros(5, 6, 2)}, "normals: expected shape"),
    ({"mask": torch.ones(5, 6)}, "mask: expected bool"),
    ({"weights": torch.ones(6, 5)}, "weights: expected shape"),
])
def test_wrong_shapes_are_refused(change, message):
    arguments = {"depth": torch.ones(5, 6), "normals": torch.ones(5, 6, 3),
                 "K": intrinsics(5, 6), "mask": torch.ones(5, 6, dtype=torch.bool),
                 "weights": None}
    arguments.update(change)
    with pytest.raises(ValueError, match=message):
        normal_consistency(**arguments)

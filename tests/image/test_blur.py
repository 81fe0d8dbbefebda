"""The SSIM window blur: native == PyTorch reference (forward and backward), zero padding,
self-adjointness, and the native op's argument checks."""

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from surgsplat.image.blur import (WINDOW_SIZE, gaussian_blur, gaussian_blur_reference,
                                 gaussian_taps, native_blur_module)

needs_native = pytest.mark.skipif(native_blur_module() is None, reason="native module not built")

# (planes, height, width): a single pixel, sizes smaller than the window, and widths that are
# not multiples of the kernel's 32-column blocks
SHAPES = [(1, 1, 1), (1, 7, 5), (15, 7, 5), (1, 37, 45), (15, 37, 45), (2, 70, 33), (3, 4, 100)]


def planes(shape, seed=0, dtype=torch.float32):
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


@pytest.mark.parametrize("shape", SHAPES)
def test_reference_is_scipy_gaussian_filter_with_zero_padding(shape):
    x = planes(shape, dtype=torch.float64)
    expected = np.stack([gaussian_filter(p, sigma=1.5, truncate=5 / 1.5, mode="constant", cval=0)
                         for p in x.numpy()])
    np.testing.assert_allclose(gaussian_blur_reference(x).numpy(), expected, atol=1e-12, rtol=0)


@needs_native
@pytest.mark.parametrize("shape", SHAPES)
def test_native_matches_reference_forward_and_backward(shape):
    x = planes(shape).requires_grad_()
    x_ref = x.detach().double().requires_grad_()
    out, out_ref = gaussian_blur(x), gaussian_blur_reference(x_ref)
    assert out.shape == shape and out.dtype == torch.float32
    assert type(out.grad_fn).__name__ == "_NativeGaussianBlurBackward"
    assert (out.double() - out_ref).abs().max().item() < 1e-5
    upstream = planes(shape, seed=1) - 0.5
    out.backward(upstream)
    out_ref.backward(upstream.double())
    assert (x.grad.double() - x_ref.grad).abs().max().item() < 1e-5


@needs_native
@pytest.mark.parametrize("shape", [(1, 7, 5), (15, 37, 45)])
def test_native_blur_is_self_adjoint(shape):
    # <B x, y> = <x, B y>: the backward (the adjoint) is the same blur
    x, y = planes(shape, seed=2) - 0.5, planes(shape, seed=3) - 0.5
    bx_y = (gaussian_blur(x).double() * y.double()).sum().item()
    x_by = (x.double() * gaussian_blur(y).double()).sum().item()
    assert bx_y == pytest.approx(x_by, rel=1e-6, abs=1e-9)
    assert abs(bx_y) > 1e-3  # not vacuous


@needs_native
def test_native_zero_padding_at_the_corner():
    # a plane of ones: the corner pixel sees the inner half of the window along each axis
    taps = gaussian_taps(torch.float64, torch.device("cpu"))
    inner = taps[WINDOW_SIZE // 2:].sum().item()
    out = gaussian_blur(torch.ones(1, 20, 30))
    assert out[0, 0, 0].item() == pytest.approx(inner ** 2, abs=1e-6)
    assert out[0, 10, 15].item() == pytest.approx(1.0, abs=1e-6)


@needs_native
def test_native_op_rejects_bad_taps_and_outputs():
    native = native_blur_module()
    x = np.zeros((2, 8, 9), dtype=np.float32)
    out = np.zeros_like(x)
    with pytest.raises(ValueError, match="symmetric"):
        native.blur(x, np.array([0.2, 0.5, 0.3], dtype=np.float32), out)
    with pytest.raises(ValueError, match="odd"):
        native.blur(x, np.array([0.5, 0.5], dtype=np.float32), out)
    with pytest.raises(ValueError, match="out"):
        native.blur(x, np.array([1.0], dtype=np.float32), np.zeros((2, 8, 8), dtype=np.float32))


def test_float64_uses_the_reference_and_gradchecks():
    x = planes((2, 6, 7), dtype=torch.float64).requires_grad_()
    torch.testing.assert_close(gaussian_blur(x), gaussian_blur_reference(x), rtol=0, atol=0)
    assert torch.autograd.gradcheck(gaussian_blur, (x,), eps=1e-6, atol=1e-8)


def test_rejects_non_plane_stacks():
    with pytest.raises(ValueError, match=r"\[P, H, W\]"):
        gaussian_blur(torch.zeros(4, 4))

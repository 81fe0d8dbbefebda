"""The native Gaussian-basis kernel (csrc/basis) against the PyTorch reference: channels and the
gradients of the weights, centres and log-widths, on every ISA variant; input checks."""

import pytest
import torch

from surgsplat.fields.gaussian_basis import deformation_channels
from surgsplat.render.native import native_module

needs_native = pytest.mark.skipif(
    native_module() is None or not hasattr(native_module(), "gaussian_basis_forward"),
    reason="native module with the gaussian_basis kernel not built")

# float32 against a float64 reference. PyTorch's own float32 evaluation of the reference is off
# by up to 1.3e-5 in both at B = 256 (sums of 256 terms), by 3e-6 at B = 8.
FORWARD_ATOL = 3e-5  # channels are sums of B weights ~N(0, 1) times basis values in [0, 1]
GRAD_RTOL = 3e-5  # max abs error relative to the largest reference gradient entry


def make_inputs(n: int, channels: int, basis: int, seed: int):
    """Weights ~N(0, 1), centres in [-0.2, 1.2], log-widths around the default width (1/(B-1)),
    some much narrower and wider; the last Gaussian's first centre sits exactly on t = 0.5."""
    generator = torch.Generator().manual_seed(seed)
    weights = torch.randn(n, channels, basis, generator=generator)
    centres = torch.rand(n, basis, generator=generator) * 1.4 - 0.2
    centres[-1, 0] = 0.5
    log_widths = (torch.log(torch.tensor(1.0 / max(basis - 1, 1)))
                  + torch.randn(n, basis, generator=generator) * 1.5)
    return weights, centres, log_widths


def channels_and_grads(inputs, t: float, upstream, backend: str, dtype=torch.float32):
    leaves = [x.to(dtype).clone().requires_grad_(True) for x in inputs]
    out = deformation_channels(*leaves, t, backend=backend)
    grads = torch.autograd.grad((out * upstream.to(dtype)).sum(), leaves)
    return out.detach(), grads


def relative_error(value, reference) -> float:
    return float((value.double() - reference).abs().max() / reference.abs().max())


@needs_native
@pytest.mark.parametrize("n, channels, basis", [(1, 10, 8), (37, 13, 2), (1000, 10, 8),
                                                (517, 10, 16), (300, 3, 5), (40, 10, 256)])
@pytest.mark.parametrize("t", [0.0, 0.5, 0.93])
def test_native_matches_reference(native_isa, n, channels, basis, t):
    inputs = make_inputs(n, channels, basis, seed=n + basis)
    upstream = torch.randn(n, channels, generator=torch.Generator().manual_seed(7))
    out, grads = channels_and_grads(inputs, t, upstream, "native")
    reference, reference_grads = channels_and_grads(inputs, t, upstream, "reference",
                                                    torch.float64)
    assert float((out.double() - reference).abs().max()) < FORWARD_ATOL
    for name, grad, expected in zip(("weights", "centres", "log_widths"), grads,
                                    reference_grads):
        assert relative_error(grad, expected) < GRAD_RTOL, name


@needs_native
def test_auto_runs_native_and_float64_runs_the_reference():
    inputs = make_inputs(64, 10, 8, seed=1)
    upstream = torch.ones(64, 10)
    auto, _ = channels_and_grads(inputs, 0.3, upstream, "auto")
    native, _ = channels_and_grads(inputs, 0.3, upstream, "native")
    assert torch.equal(auto, native)
    double, _ = channels_and_grads(inputs, 0.3, upstream, "auto", torch.float64)
    assert double.dtype == torch.float64
    with pytest.raises(ValueError, match="float32"):
        channels_and_grads(inputs, 0.3, upstream, "native", torch.float64)


@needs_native
def test_native_rejects_bad_shapes():
    weights, centres, log_widths = make_inputs(8, 10, 4, seed=2)
    with pytest.raises(ValueError, match="centres"):
        deformation_channels(weights, centres[:, :3], log_widths, 0.5, backend="native")
    wide = torch.zeros(2, 10, 257)
    with pytest.raises(ValueError, match="B <= 256"):
        deformation_channels(wide, torch.zeros(2, 257), torch.zeros(2, 257), 0.5,
                             backend="native")

"""The Gaussian window of SSIM as a separable blur of image planes, zero padding, 'same' size.

11 taps with sigma 1.5 (Wang et al. 2004), filtered along rows then columns; pixels outside the
image read as zero, as in the 3DGS / EndoNeRF-family evaluation code (conv2d with
padding = window // 2). Two implementations with one contract: the native CPU kernel in
csrc/blur (float32) and a PyTorch depthwise convolution (any dtype, device-agnostic).
`gaussian_blur` picks the native kernel for float32 CPU planes when it is built. The kernel is
symmetric and the padding is zero, so the blur is self-adjoint: its backward is the same blur
of the upstream gradient. (SSIM itself runs on fused native kernels built on the same blur, see
`surgsplat.image.ssim`.)
"""

from __future__ import annotations

from types import ModuleType

import torch
import torch.nn.functional as F
from torch import Tensor

from surgsplat.render.native import native_module

WINDOW_SIZE = 11
SIGMA = 1.5


def gaussian_taps(dtype: torch.dtype, device: torch.device) -> Tensor:
    """[11] normalised 1D Gaussian window."""
    offsets = torch.arange(WINDOW_SIZE, dtype=dtype, device=device) - WINDOW_SIZE // 2
    taps = torch.exp(-offsets ** 2 / (2 * SIGMA ** 2))
    return taps / taps.sum()


def gaussian_blur_reference(planes: Tensor) -> Tensor:
    """[P, H, W] -> [P, H, W]: the blur as one depthwise (grouped) convolution per axis.

    The planes are the channels of one grouped convolution, which PyTorch runs far faster on CPU
    than a batch of single-channel convolutions. Differentiable by autograd.
    """
    count = planes.shape[0]
    # a real (not expanded) weight tensor: conv2d takes a far slower path on stride-0 weights
    taps = gaussian_taps(planes.dtype, planes.device).repeat(count, 1)  # [P, 11]
    radius = WINDOW_SIZE // 2
    rows = F.conv2d(planes.unsqueeze(0), taps.reshape(count, 1, 1, WINDOW_SIZE),
                    padding=(0, radius), groups=count)
    return F.conv2d(rows, taps.reshape(count, 1, WINDOW_SIZE, 1), padding=(radius, 0),
                    groups=count)[0]


def native_blur_module() -> ModuleType | None:
    """The native module when it is built with the kernels of csrc/blur (blur, SSIM), else None
    (as after `native_module()`'s warning, or with a build older than these kernels)."""
    native = native_module()
    return native if native is not None and hasattr(native, "blur") else None


def _native_blur(planes: Tensor) -> Tensor:
    """[P, H, W] float32 -> blurred copy, by the native kernel (no autograd)."""
    out = torch.empty_like(planes)
    taps = gaussian_taps(torch.float32, planes.device)
    native_blur_module().blur(planes.numpy(), taps.numpy(), out.numpy())
    return out


class _NativeGaussianBlur(torch.autograd.Function):
    """Autograd wrapper of the native blur; backward is the same blur (self-adjoint)."""

    @staticmethod
    def forward(ctx, planes):
        return _native_blur(planes.detach().contiguous())

    @staticmethod
    def backward(ctx, grad):
        return _NativeGaussianBlur.apply(grad.contiguous())


def gaussian_blur(planes: Tensor) -> Tensor:
    """[P, H, W] -> [P, H, W]: each plane blurred by the 11x11 Gaussian window, zero padding.

    Native kernel for float32 CPU planes when it is built, else `gaussian_blur_reference`;
    differentiable either way.
    """
    if planes.dim() != 3:
        raise ValueError(f"expected planes [P, H, W], got shape {tuple(planes.shape)}")
    native = planes.dtype == torch.float32 and planes.device.type == "cpu"
    if native and native_blur_module() is not None:
        return _NativeGaussianBlur.apply(planes)
    return gaussian_blur_reference(planes)


"""Rasterisation of screen-space Gaussians into N feature channels: one contract, two backends.

`native`: the C++/OpenMP tile kernels in csrc/rasterize (float32). `reference`: the dense
PyTorch version in reference.py (any dtype, autograd). `auto` picks native for float32 inputs
when it is built.
"""

from __future__ import annotations

import torch
from torch import Tensor

from surgsplat.render.native import Backend, dense_grad, native_module, resolve_backend
from surgsplat.render.pixel_weights import PixelWeights, check_pixel_weights
from surgsplat.render.reference import rasterize_reference


class _NativeRasterize(torch.autograd.Function):
    """Autograd wrapper of the native forward/backward kernels."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, depths, radii, background, width,
                height, absgrad, gradient_weights):
        native = native_module()
        inputs = [t.detach().contiguous() for t in (means2d, conics, opacities, features)]
        channels = features.shape[1]
        if background is None:
            background = torch.zeros(channels)
        image = torch.empty(height, width, channels)
        transmittance = torch.empty(height, width)
        last_entry = torch.empty(height, width, dtype=torch.int32)
        bins = native.rasterize_forward(
            *(t.numpy() for t in inputs), depths.detach().contiguous().numpy(),
            radii.contiguous().numpy(), background.detach().contiguous().numpy(), width, height,
            image.numpy(), transmittance.numpy(), last_entry.numpy())
        ctx.bins, ctx.size, ctx.absgrad = bins, (width, height), absgrad
        ctx.gradient_weights = (torch.empty(0), torch.empty(0, dtype=torch.uint8))
        if gradient_weights is not None:  # the kernel's form: float32 weights, 1-byte members
            ctx.gradient_weights = (
                gradient_weights.weights.detach().to(torch.float32).contiguous(),
                gradient_weights.members.to(torch.uint8).contiguous())
        ctx.save_for_backward(*inputs, transmittance, last_entry)
        return image, 1.0 - transmittance

    @staticmethod
    def backward(ctx, grad_image, grad_alpha):
        native = native_module()
        means2d, conics, opacities, features, transmittance, last_entry = ctx.saved_tensors
        width, height = ctx.size
        grads = [torch.empty_like(means2d), torch.empty_like(conics),
                 torch.empty_like(opacities), torch.zeros_like(features)]
        abs_grad = torch.empty_like(means2d)
        native.rasterize_backward(
            ctx.bins, means2d.numpy(), conics.numpy(), opacities.numpy(), features.numpy(),
            width, height, transmittance.numpy(), last_entry.numpy(),
            dense_grad(grad_image, (height, width, features.shape[1])).numpy(),
            dense_grad(grad_alpha, (height, width)).numpy(), *(g.numpy() for g in grads),
            abs_grad.numpy(), *(g.numpy() for g in ctx.gradient_weights))
        if ctx.absgrad is not None:
            ctx.absgrad += abs_grad.norm(dim=1)
        return (*grads, None, None, None, None, None, None, None)


class NonFiniteError(ValueError):
    """An input of the rasterizer holds NaN or Inf entries."""


def check_finite(**tensors: Tensor) -> None:
    """NonFiniteError naming the first input with NaN or Inf entries (one reduction per tensor on
    the fast path: a finite sum means finite entries, barring float overflow)."""
    for name, tensor in tensors.items():
        if not bool(torch.isfinite(tensor.sum())) and not bool(torch.isfinite(tensor).all()):
            bad = int((~torch.isfinite(tensor)).sum())
            raise NonFiniteError(f"rasterize: {name} has {bad} non-finite (NaN or Inf) entries")


def rasterize(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor,
              depths: Tensor, radii: Tensor, width: int, height: int,
              absgrad: Tensor | None = None, background: Tensor | None = None,
              gradient_weights: PixelWeights | None = None,
              backend: Backend = "auto") -> tuple[Tensor, Tensor]:
    """Alpha-composite Gaussians front to back into (image [H,W,C], alpha [H,W]).

    means2d [N,2] pixels, conics [N,3] (a, b, c), opacities [N] in [0,1], features [N,C] (any C),
    depths [N] (sort key), radii [N] int (0 = culled: not drawn, no gradient).
    background [C], when given, is composited behind the Gaussians: image + (1 - alpha) background
    (data: it gets no gradient).
    absgrad [N], when given, receives during backward the per-Gaussian sum over pixels of the
    absolute screen-space gradient of the mean (the norm of the summed |dL/dx|, |dL/dy|).
    gradient_weights, when given, scales some Gaussians' gradients per pixel (PixelWeights).
    Raises ValueError on NaN/Inf inputs (project() keeps culled Gaussians finite).
    """
    if features.ndim != 2 or features.shape[0] != means2d.shape[0]:
        raise ValueError(f"rasterize: features must be [N, C] with N = {means2d.shape[0]}, "
                         f"got {tuple(features.shape)}")
    if background is not None and background.shape != features.shape[1:]:
        raise ValueError(f"rasterize: background must be [C] = [{features.shape[1]}], "
                         f"got {tuple(background.shape)}")
    if width < 1 or height < 1:
        raise ValueError(f"rasterize: image size must be positive, got {width}x{height}")
    if gradient_weights is not None:
        check_pixel_weights(gradient_weights, width, height, means2d.shape[0])
    check_finite(means2d=means2d.detach(), conics=conics.detach(), opacities=opacities.detach(),
                 features=features.detach(), depths=depths.detach())
    if resolve_backend("rasterize", backend, [means2d, conics, opacities, features]) == "reference":
        return rasterize_reference(means2d, conics, opacities, features, depths, radii,
                                   width, height, absgrad, background, gradient_weights)
    radii = radii.to(torch.int32)
    return _NativeRasterize.apply(means2d, conics, opacities, features, depths, radii,
                                  background, width, height, absgrad, gradient_weights)

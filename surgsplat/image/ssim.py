"""Structural similarity (SSIM, Wang et al. 2004), differentiable, for metrics and the D-SSIM loss.

Constants as in the paper: an 11x11 Gaussian window with sigma 1.5, C1 = (0.01 L)^2 and
C2 = (0.03 L)^2 with dynamic range L = 1 (images in [0, 1]). Each channel is filtered on its own
with the separable Gaussian blur of `surgsplat.image.blur`. The SSIM map has the input's size
('same') with ZERO padding: pixels outside the image read as 0, as in the 3DGS /
EndoNeRF-family evaluation code (conv2d with padding = window // 2), so that scores compare with
the papers'. The windows of border pixels thus see zeros in both images, which pulls their local
means and variances towards 0. The SSIM score is the mean of the map over all pixels and
channels, or over the masked pixels.

Two implementations with one contract: for float32 CPU images, the fused native kernels of
csrc/blur (the map, or directly its masked sum for `ssim`, and the backward, each in one streamed
pass of the blur; the training loss calls them every step); otherwise `ssim_map_reference`,
composed of PyTorch ops and differentiated by autograd.
Computed in the inputs' dtype: float32 agrees with a float64 reference to about 1e-4 per pixel,
as the variances E[x^2] - E[x]^2 lose digits; the metrics in `image_metrics` pass float64 images.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from surgsplat.image.blur import gaussian_blur, gaussian_taps, native_blur_module

C1 = 0.01 ** 2
C2 = 0.03 ** 2


def _native_forward(pred: Tensor, gt: Tensor, weights: Tensor | None, image_mask: Tensor | None,
                    values: Tensor | None) -> tuple[float, Tensor, Tensor]:
    """The native forward: (score, moments [4, C, H, W], taps); writes the map into `values`.
    image_mask [H, W], unless None, multiplies both images before filtering."""
    height, width, channels = pred.shape
    moments = torch.empty(4, channels, height, width)  # blurred x, y, x^2 + y^2, xy
    taps = gaussian_taps(torch.float32, pred.device)
    score = native_blur_module().ssim_forward(
        pred.numpy(), gt.numpy(), taps.numpy(), C1, C2,
        None if weights is None else weights.numpy(),
        None if image_mask is None else image_mask.numpy(), moments.numpy(),
        None if values is None else values.numpy())
    return score, moments, taps


def _native_backward(ctx, grad_map: Tensor | None, weights: Tensor | None, grad_score: float,
                     image_mask: Tensor | None = None) -> tuple[Tensor | None, Tensor | None]:
    """Gradients for pred and gt (None where not needed) from the saved forward state."""
    pred, gt, moments, taps = ctx.saved_tensors[:4]
    grad_pred, grad_gt = (torch.empty_like(image) if needed else None
                          for image, needed in zip((pred, gt), ctx.needs_input_grad[:2]))
    native_blur_module().ssim_backward(
        pred.numpy(), gt.numpy(), moments.numpy(), taps.numpy(), C1, C2,
        None if grad_map is None else grad_map.contiguous().numpy(),
        None if weights is None else weights.numpy(), grad_score,
        None if image_mask is None else image_mask.numpy(),
        None if grad_pred is None else grad_pred.numpy(),
        None if grad_gt is None else grad_gt.numpy())
    return grad_pred, grad_gt


class _NativeSSIMMap(torch.autograd.Function):
    """The native SSIM map [H, W, C] (float32, CPU) with its backward."""

    @staticmethod
    def forward(ctx, pred, gt):
        pred, gt = pred.detach().contiguous(), gt.detach().contiguous()
        values = torch.empty_like(pred)
        _, moments, taps = _native_forward(pred, gt, None, None, values)
        ctx.save_for_backward(pred, gt, moments, taps)
        return values

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        return _native_backward(ctx, grad, None, 0.0)


class _NativeSSIMScore(torch.autograd.Function):
    """sum over pixels and channels of weights [H, W] (None: ones) times the native SSIM map of
    the images, each multiplied by the weights first when mask_images, without writing the map
    or the masked images (float32, CPU), with its backward."""

    @staticmethod
    def forward(ctx, pred, gt, weights, mask_images):
        pred, gt = pred.detach().contiguous(), gt.detach().contiguous()
        image_mask = weights if mask_images else None
        score, moments, taps = _native_forward(pred, gt, weights, image_mask, None)
        ctx.save_for_backward(pred, gt, moments, taps, weights)
        ctx.mask_images = mask_images
        return torch.tensor(score, dtype=pred.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        weights = ctx.saved_tensors[4]
        image_mask = weights if ctx.mask_images else None
        return *_native_backward(ctx, None, weights, float(grad), image_mask), None, None


def _check_pair(pred: Tensor, gt: Tensor) -> None:
    if pred.shape != gt.shape or pred.dim() != 3:
        raise ValueError(f"expected two images of one shape [H, W, C], got {tuple(pred.shape)} "
                         f"and {tuple(gt.shape)}")


def ssim_map_reference(pred: Tensor, gt: Tensor) -> Tensor:
    """`ssim_map` composed of PyTorch ops and `gaussian_blur` (any dtype, autograd): the five
    blurred maps E[x], E[y], E[x^2], E[y^2], E[xy] of all channels in one blur of stacked planes."""
    _check_pair(pred, gt)
    channels = pred.shape[2]
    x = pred.permute(2, 0, 1)  # [C, H, W]
    y = gt.permute(2, 0, 1)
    moments = gaussian_blur(torch.cat([x, y, x * x, y * y, x * y]))  # [5C, H, W]
    mu_x, mu_y, xx, yy, xy = moments.split(channels)
    var_x = xx - mu_x * mu_x
    var_y = yy - mu_y * mu_y
    cov = xy - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + C1) * (2 * cov + C2)
    denominator = (mu_x * mu_x + mu_y * mu_y + C1) * (var_x + var_y + C2)
    return (numerator / denominator).permute(1, 2, 0)  # [H, W, C]


def _use_native(pred: Tensor, gt: Tensor) -> bool:
    """Whether the native kernels take these images: float32 on the CPU, and built."""
    return (pred.dtype == gt.dtype == torch.float32 and pred.device.type == gt.device.type == "cpu"
            and native_blur_module() is not None)


def ssim_map(pred: Tensor, gt: Tensor) -> Tensor:
    """[H, W, C] per-pixel, per-channel SSIM of two images [H, W, C] in [0, 1].

    Differentiable with respect to both inputs; any size (zero padding). Native kernels for
    float32 CPU images when built, else `ssim_map_reference`.
    """
    _check_pair(pred, gt)
    if _use_native(pred, gt):
        return _NativeSSIMMap.apply(pred, gt)
    return ssim_map_reference(pred, gt)


def ssim(pred: Tensor, gt: Tensor, mask: Tensor | None = None,
         zero_unmasked: bool = False) -> Tensor:
    """Scalar SSIM of two images [H, W, C] in [0, 1].

    Without a mask: the mean of `ssim_map` over all pixels and channels. With a mask (bool [H, W],
    True = count the pixel): the mean of the map over the masked pixels and all channels; the
    images themselves are not altered, so windows centred on counted pixels still see their
    uncounted neighbours, unless zero_unmasked: then the unmasked pixels read as 0 in both
    images (the masked D-SSIM loss). Differentiable; `1 - ssim(...)` is the D-SSIM loss. The
    native path masks the images and sums the masked map inside the kernel, without
    materialising either.
    """
    _check_pair(pred, gt)
    height, width, channels = pred.shape
    if mask is not None and (mask.shape != (height, width) or mask.dtype != torch.bool):
        raise ValueError(f"expected a bool mask of shape {(height, width)}, got {mask.dtype} "
                         f"{tuple(mask.shape)}")
    count = height * width if mask is None else int(mask.sum())
    if mask is not None and count == 0:
        raise ValueError("the SSIM mask selects no pixel")
    if zero_unmasked and mask is None:
        raise ValueError("zero_unmasked needs a mask")
    weights = None if mask is None else mask.to(pred.dtype)  # [H, W]
    if _use_native(pred, gt):
        return _NativeSSIMScore.apply(pred, gt, weights, zero_unmasked) / (count * channels)
    if zero_unmasked:
        pred, gt = pred * weights.unsqueeze(-1), gt * weights.unsqueeze(-1)
    values = ssim_map_reference(pred, gt)  # [H, W, C]
    if weights is None:
        return values.mean()
    # the masked sum as a matrix-vector product: several times faster than values[mask] (an
    # index gather and scatter) or a select, forward and backward
    return (weights.reshape(1, -1) @ values.reshape(-1, channels)).sum() / (count * channels)

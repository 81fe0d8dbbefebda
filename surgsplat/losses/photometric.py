"""Photometric losses over the tissue pixels of a frame: L1, D-SSIM and their 3DGS blend.

Images are float [H, W, C] in [0, 1]; masks are bool [H, W] with True = count the pixel (tissue).
Pixels outside the mask never influence a loss: L1 averages over the masked pixels, and D-SSIM
zeroes the unmasked pixels in both images before filtering (as published endoscopic
Gaussian-splat code does with its tool masks), so the SSIM windows of masked pixels near a tool
see the same zeros in both images, whatever the tool pixels held.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from surgsplat.image.ssim import ssim
from surgsplat.losses.occlusion import OcclusionImportance
from surgsplat.model.component import Component, ComponentConfig, RenderContext, SetupContext
from surgsplat.model.phases import Phase


def _check(pred: Tensor, gt: Tensor, mask: Tensor) -> None:
    if pred.shape != gt.shape or pred.dim() != 3:
        raise ValueError(f"expected two images of one shape [H, W, C], got {tuple(pred.shape)} "
                         f"and {tuple(gt.shape)}")
    if mask.shape != pred.shape[:2] or mask.dtype != torch.bool:
        raise ValueError(f"expected a bool mask of shape {tuple(pred.shape[:2])}, got "
                         f"{mask.dtype} {tuple(mask.shape)}")


class _WeightedAbsSum(torch.autograd.Function):
    """sum over pixels and channels of weights [H, W] * |pred - gt| [H, W, C], differentiable in
    pred only (gt and the weights are data). Its gradient sign(pred - gt) * weights is written
    directly: autograd's chain of image-sized ops (subtract, abs, broadcast multiply, sum, and
    their backward) costs about twice as much per step."""

    @staticmethod
    def forward(ctx, pred: Tensor, gt: Tensor, weights: Tensor) -> Tensor:
        diff = pred.detach() - gt
        per_value = weights.unsqueeze(-1).expand_as(diff).contiguous()  # [H, W, C]
        ctx.save_for_backward(diff, per_value)
        return torch.dot(diff.abs().view(-1), per_value.view(-1))

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None, None]:
        diff, per_value = ctx.saved_tensors
        return diff.sign().mul_(per_value).mul_(grad), None, None


def masked_l1(pred: Tensor, gt: Tensor, mask: Tensor, weights: Tensor | None = None) -> Tensor:
    """Mean absolute difference over the masked pixels and all channels; 0 if the mask is empty.
    With `weights` [H, W] (e.g. an occlusion importance map, 0 off the mask), each pixel's
    difference is multiplied by its weight before the mean over the masked pixels.
    Differentiable in `pred`; `gt` and `weights` are data and must not require gradients."""
    _check(pred, gt, mask)
    if gt.requires_grad or (weights is not None and weights.requires_grad):
        raise ValueError("masked_l1: gt and weights are data and must not require gradients")
    count = mask.sum().clamp_min(1) * pred.shape[2]
    per_pixel = mask.to(pred.dtype) if weights is None else weights * mask
    return _WeightedAbsSum.apply(pred.contiguous(), gt.contiguous(), per_pixel) / count


def d_ssim(pred: Tensor, gt: Tensor, mask: Tensor) -> Tensor:
    """1 - SSIM (the 3DGS convention, in [0, 2]) over the masked pixels, with unmasked pixels
    zeroed in both images; 0 if the mask is empty."""
    _check(pred, gt, mask)
    if not mask.any():
        return pred.sum() * 0.0
    return 1.0 - ssim(pred, gt, mask, zero_unmasked=True)


def photometric_loss(pred: Tensor, gt: Tensor, mask: Tensor, lambda_dssim: float,
                     weights: Tensor | None = None) -> Tensor:
    """(1 - lambda) L1 + lambda D-SSIM over the masked pixels (3DGS uses lambda = 0.2);
    D-SSIM is not computed when lambda is 0. `weights` [H, W] weight the L1 term's pixels."""
    pred = pred.contiguous()  # one copy for both terms (a render's colour is a strided view)
    loss = masked_l1(pred, gt, mask, weights)
    if lambda_dssim == 0:
        return loss
    return (1.0 - lambda_dssim) * loss + lambda_dssim * d_ssim(pred, gt, mask)


@dataclass
class PhotometricConfig(ComponentConfig, kind="photometric_loss"):
    """The photometric loss of a method."""

    lambda_dssim: float = field(default=0.2, metadata={"range": "[0, 1]"})
    """Weight of D-SSIM against L1 (3DGS uses 0.2; 0 = L1 only)."""
    occlusion_gamma: float = field(default=0.0, metadata={"range": "[0, inf)"})
    """gamma of the occlusion importance map weighting the L1 term (`losses.occlusion`); 0 =
    every tissue pixel weighs 1."""

    def build(self) -> "PhotometricLoss":
        return PhotometricLoss(self)


class PhotometricLoss(Component):
    """Loss term "photometric": `photometric_loss` of the rendered colour over tissue pixels,
    the L1 term weighted by the occlusion importance map when occlusion_gamma > 0."""
    phase = Phase.LOSS
    reads_time = False

    def __init__(self, config: PhotometricConfig):
        super().__init__()
        self.config = config
        self.importance = OcclusionImportance(config.occlusion_gamma)

    def setup(self, context: SetupContext) -> None:
        self.importance.observe(context.frames)

    def loss_names(self) -> tuple[str, ...]:
        return ("photometric",)

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        frame = context.frame
        weights = self.importance.weights(frame) if self.config.occlusion_gamma > 0 else None
        return {"photometric": photometric_loss(context.output.rgb, frame.image, frame.tissue,
                                                self.config.lambda_dssim, weights)}

"""Image-quality metrics with tool pixels excluded, in the two conventions papers use.

- "zeroed" (the EndoNeRF-style evaluation convention): tool pixels are set to 0 in both images and
  the metric is taken over ALL pixels of the image, so the zeroed tool pixels count as perfect
  matches and raise the score as the tool covers more of the frame.
- "tissue": the metric is averaged over tissue pixels only.

All functions take `pred` and `gt` as float [H, W, 3] tensors in [0, 1] and `tissue` as a bool
[H, W] tensor (True = tissue, False = tool), and return Python floats. PSNR uses a peak value of 1.
Both are computed in float64.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from surgsplat.image.ssim import ssim


def _check(pred: Tensor, gt: Tensor, tissue: Tensor) -> None:
    if pred.shape != gt.shape or pred.dim() != 3 or pred.shape[2] != 3:
        raise ValueError(f"expected two images of one shape [H, W, 3], got {tuple(pred.shape)} "
                         f"and {tuple(gt.shape)}")
    if tissue.shape != pred.shape[:2] or tissue.dtype != torch.bool:
        raise ValueError(f"expected a bool tissue mask of shape {tuple(pred.shape[:2])}, got "
                         f"{tissue.dtype} {tuple(tissue.shape)}")
    if not tissue.any():
        raise ValueError("the tissue mask selects no pixel")


def _psnr(squared_errors: Tensor) -> float:
    """PSNR (peak 1) of the mean of the given squared errors; inf when they are all zero."""
    mse = squared_errors.double().mean().item()
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


def psnr_zeroed(pred: Tensor, gt: Tensor, tissue: Tensor) -> float:
    """PSNR with tool pixels set to 0 in both images; MSE over all H*W*3 values."""
    _check(pred, gt, tissue)
    keep = tissue.unsqueeze(-1)  # [H, W, 1]
    return _psnr(((pred - gt) * keep) ** 2)


def psnr_tissue(pred: Tensor, gt: Tensor, tissue: Tensor) -> float:
    """PSNR with the MSE over the values of tissue pixels only (3 per tissue pixel)."""
    _check(pred, gt, tissue)
    return _psnr((pred[tissue] - gt[tissue]) ** 2)


def ssim_zeroed(pred: Tensor, gt: Tensor, tissue: Tensor) -> float:
    """SSIM of the two images with tool pixels set to 0 in both, averaged over all pixels."""
    _check(pred, gt, tissue)
    keep = tissue.unsqueeze(-1).double()  # [H, W, 1]
    return ssim(pred.double() * keep, gt.double() * keep).item()


def ssim_tissue(pred: Tensor, gt: Tensor, tissue: Tensor) -> float:
    """SSIM map of the unaltered images averaged over tissue pixels only (see `ssim`)."""
    _check(pred, gt, tissue)
    return ssim(pred.double(), gt.double(), mask=tissue).item()

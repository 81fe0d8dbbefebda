"""Depth losses against a measured depth map, over tissue pixels that have a measurement.

Depths are float [H, W] in the scene's depth unit (e.g. millimetres); a ground-truth depth of 0
means "no measurement". Masks are bool [H, W] with True = count the pixel (tissue). Both losses
average over the counted pixels and are 0 when there is none.
"""

from __future__ import annotations

import torch
from torch import Tensor


def valid_depth_pixels(pred_depth: Tensor, gt: Tensor, mask: Tensor) -> Tensor:
    """[H, W] bool: masked pixels with a measured (positive) depth; ValueError when the depth
    maps [H, W] and the bool mask [H, W] do not match."""
    if pred_depth.shape != gt.shape or pred_depth.dim() != 2:
        raise ValueError(f"expected two depth maps of one shape [H, W], got "
                         f"{tuple(pred_depth.shape)} and {tuple(gt.shape)}")
    if mask.shape != gt.shape or mask.dtype != torch.bool:
        raise ValueError(f"expected a bool mask of shape {tuple(gt.shape)}, got {mask.dtype} "
                         f"{tuple(mask.shape)}")
    return mask & (gt > 0)


def _mean_over(errors: Tensor, valid: Tensor) -> Tensor:
    weights = valid.to(errors.dtype)
    return (errors * weights).sum() / weights.sum().clamp_min(1.0)


def depth_l1(pred_depth: Tensor, gt: Tensor, mask: Tensor) -> Tensor:
    """Mean |pred - gt| (depth units) over masked pixels with gt > 0."""
    valid = valid_depth_pixels(pred_depth, gt, mask)
    return _mean_over((pred_depth - gt).abs(), valid)


def inverse_depth_l1(pred_depth: Tensor, gt: Tensor, mask: Tensor) -> Tensor:
    """Mean |1/pred - 1/gt| (1 / depth units) over masked pixels with gt > 0 and pred > 0.

    Pixels the render leaves at depth 0 (nothing drawn) have no inverse depth and are skipped.
    """
    valid = valid_depth_pixels(pred_depth, gt, mask) & (pred_depth > 0)
    # Invalid pixels get depth 1 before inverting, so that no inf or nan enters the graph.
    safe_pred = torch.where(valid, pred_depth, torch.ones_like(pred_depth))
    safe_gt = torch.where(valid, gt, torch.ones_like(gt))
    return _mean_over((1.0 / safe_pred - 1.0 / safe_gt).abs(), valid)

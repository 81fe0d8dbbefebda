"""Depth-map helpers shared by the depth losses and the depth metrics.

Depths are float [H, W] in the scene's depth unit (millimetres for the phantom); a measured depth
of 0 means "no measurement".
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


def depth_gradient_magnitude(depth: Tensor) -> Tensor:
    """[H, W] |grad D| of a depth map [H, W] by central differences (one-sided at the border),
    in depth units per pixel."""
    dy, dx = torch.gradient(depth)
    return torch.sqrt(dx * dx + dy * dy)

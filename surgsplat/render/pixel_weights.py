"""Per-pixel weights of some Gaussians' gradients in a rasterisation: what a component gives the
renderer to keep Gaussians from, or let them learn less from, chosen pixels (both backends of
rasterize.py take them)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class PixelWeights:
    """Per-pixel weights of some Gaussians' gradients in one rasterisation: the Gaussians
    `members` [N] bool learn from pixel p with its gradient scaled by `weights` [H, W] (float,
    in [0, 1]): 0 keeps the pixel's gradient from them, 1 passes it whole. Their values
    composite unchanged, and every other Gaussian's gradient is unchanged: the derivative of
    pixel p with respect to a member's own inputs is taken as weights[p] times its true value
    (e.g. tissue learns nothing from the pixels that show the tool in front of it)."""

    weights: Tensor
    members: Tensor


def check_pixel_weights(pixel_weights: PixelWeights, width: int, height: int, n: int) -> None:
    """ValueError unless the weights are [H, W] in [0, 1] and the members [N] bool."""
    weights, members = pixel_weights.weights, pixel_weights.members
    if weights.shape != (height, width) or members.shape != (n,):
        raise ValueError(f"rasterize: gradient weights must be [H, W] = [{height}, {width}] and "
                         f"their members [N] = [{n}], got {tuple(weights.shape)} and "
                         f"{tuple(members.shape)}")
    if members.dtype != torch.bool or not weights.is_floating_point():
        raise ValueError(f"rasterize: gradient weights must be float and their members bool, got "
                         f"{weights.dtype} and {members.dtype}")
    if not bool(((weights >= 0) & (weights <= 1)).all()):
        raise ValueError("rasterize: gradient weights must lie in [0, 1]")

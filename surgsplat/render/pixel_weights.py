"""Per-pixel weights of some Gaussians' gradients in a rasterisation: what a component gives the
renderer to keep Gaussians from, or let them learn less from, chosen pixels (both backends of
rasterize.py take them)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class PixelWeights:
    """Per-pixel weights of the gradients of groups of Gaussians in one rasterisation: a
    Gaussian of group `groups[i]` = g >= 1 learns from pixel p with its gradient scaled by
    `weights[g - 1, p]` (float, in [0, 1]): 0 keeps the pixel's gradient from it, 1 passes it
    whole; group 0 is not weighted. weights: [G, H, W]; groups: [N] integer in [0, G]. Every
    value composites unchanged, and the other Gaussians' gradients are unchanged: the
    derivative of pixel p with respect to a weighted Gaussian's own inputs is taken as its
    weight at p times its true value (e.g. tissue learns nothing from the pixels that show the
    tool in front of it)."""

    weights: Tensor
    groups: Tensor

    @classmethod
    def of_members(cls, weights: Tensor, members: Tensor) -> "PixelWeights":
        """One group: the Gaussians `members` [N] bool, weighted by `weights` [H, W]."""
        return cls(weights[None], members.to(torch.uint8))


def check_pixel_weights(pixel_weights: PixelWeights, width: int, height: int, n: int) -> None:
    """ValueError unless the weights are [G, H, W] in [0, 1] (1 <= G <= 255) and the groups [N]
    integers in [0, G]."""
    weights, groups = pixel_weights.weights, pixel_weights.groups
    if (weights.dim() != 3 or weights.shape[1:] != (height, width)
            or not 1 <= weights.shape[0] <= 255 or groups.shape != (n,)):
        raise ValueError(f"rasterize: gradient weights must be [G, H, W] = [G, {height}, {width}] "
                         f"with 1 <= G <= 255 and their groups [N] = [{n}], got "
                         f"{tuple(weights.shape)} and {tuple(groups.shape)}")
    if groups.is_floating_point() or groups.dtype == torch.bool or not weights.is_floating_point():
        raise ValueError(f"rasterize: gradient weights must be float and their groups integer, "
                         f"got {weights.dtype} and {groups.dtype}")
    if n and not bool(((groups >= 0) & (groups <= weights.shape[0])).all()):
        raise ValueError(f"rasterize: gradient weight groups must lie in [0, {weights.shape[0]}]")
    if not bool(((weights >= 0) & (weights <= 1)).all()):
        raise ValueError("rasterize: gradient weights must lie in [0, 1]")

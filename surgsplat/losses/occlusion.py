"""Endo-GSG's occlusion importance map (Eq. 11-12): image losses weighted toward the tissue that
tools hide most often.

With M_j the tool mask of training frame j (1 = tool), the occlusion frequency is
S = sum_j M_j / ||sum_j M_j||_F (Frobenius norm over the image), and the importance map of frame
i is V_i = (1 - M_i) (1 + gamma S): 0 on the frame's own tool pixels, more where tools pass often.
Pixels outside the field of view get weight 0 too.

The losses of Eq. 12 average their weighted errors over the tissue pixels, so V_i as written would
also scale the whole loss by mean(V_i) > 1, by a different factor in every frame (the paper's
weights lambda_1, lambda_2 were tuned with V_i in the loss, on its data). `weights` therefore
returns V_i divided by its mean over the frame's tissue pixels: the map only re-weights pixels
within a frame, so the losses' weights mean the same with and without it, for any gamma.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from surgsplat.data.scene import Frame


def occlusion_frequency(tool_masks: Sequence[Tensor]) -> Tensor:
    """[H, W] float: the summed bool tool masks [H, W] over their Frobenius norm (Eq. 11);
    zeros when no mask has a tool pixel."""
    total = torch.stack([mask.float() for mask in tool_masks]).sum(dim=0)
    norm = total.norm()
    return total / norm if norm > 0 else total


class OcclusionImportance:
    """The importance map of each frame for one gamma; see the module docstring."""

    def __init__(self, gamma: float):
        if gamma < 0:
            raise ValueError(f"occlusion gamma must be >= 0, got {gamma}")
        self.gamma = gamma
        self.frequency: Tensor | None = None  # [H, W], set by `observe`

    def observe(self, frames: Sequence[Frame]) -> None:
        """Accumulate the tool masks of the training frames."""
        self.frequency = occlusion_frequency([frame.tool for frame in frames])

    def weights(self, frame: Frame) -> Tensor:
        """[H, W] float of `frame`: V_i (Eq. 11), 0 off tissue and 1 + gamma S on tissue, divided
        by its mean over the tissue pixels (so that mean is 1; all zeros without tissue)."""
        if self.frequency is None:
            raise RuntimeError("OcclusionImportance.observe must see the training frames first")
        importance = frame.tissue.float() * (1.0 + self.gamma * self.frequency)
        mean = importance.sum() / frame.tissue.sum().clamp_min(1)
        return importance / mean.clamp_min(1e-12)

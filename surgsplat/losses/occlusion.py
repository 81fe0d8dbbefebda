"""The occlusion importance map: image losses weighted toward the tissue that tools hide most
often.

With M_j the tool mask of training frame j (1 = tool), the occlusion frequency is
S = sum_j M_j / ||sum_j M_j||_F (Frobenius norm over the image), and the importance map of frame
i is V_i = (1 - M_i) (1 + gamma S): 0 on the frame's own tool pixels, more where tools pass often.
Pixels outside the field of view get weight 0 too.

The weighted losses average their weighted errors over the tissue pixels, so V_i as written
would also scale the whole loss by mean(V_i) > 1, by a different factor in every frame, and the
loss weights would mean something else for every gamma. `weights` therefore returns V_i divided
by its mean over the frame's tissue pixels: the map only re-weights pixels within a frame, so
the losses' weights mean the same with and without it, for any gamma.

S is computed once from the training frames, when a run starts, and kept as a buffer: it is
saved in the checkpoint of the loss that owns the map, so a resumed run weights as before.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from surgsplat.data.scene import Frame
from surgsplat.errors import SurgsplatError


def occlusion_frequency(tool_masks: Sequence[Tensor]) -> Tensor:
    """[H, W] float: the summed bool tool masks [H, W] over their Frobenius norm (S above);
    zeros when no mask has a tool pixel."""
    total = torch.stack([mask.float() for mask in tool_masks]).sum(dim=0)
    norm = total.norm()
    return total / norm if norm > 0 else total


class OcclusionImportance(nn.Module):
    """The importance map of each frame for one gamma; see the module docstring. A submodule of
    the loss component that uses it, so its `frequency` buffer is part of that component's
    state_dict."""

    def __init__(self, gamma: float):
        super().__init__()
        if gamma < 0:
            raise ValueError(f"occlusion gamma must be >= 0, got {gamma}")
        self.gamma = gamma
        self.register_buffer("frequency", None)  # [H, W] float S, set by `observe`

    def observe(self, frames: Sequence[Frame]) -> None:
        """Accumulate the tool masks of the training frames (nothing to do when gamma is 0:
        the map is then the tissue mask)."""
        if self.gamma > 0:
            self.frequency = occlusion_frequency([frame.tool for frame in frames])

    def weights(self, frame: Frame) -> Tensor:
        """[H, W] float of `frame`: V_i, 0 off tissue and 1 + gamma S on tissue, divided
        by its mean over the tissue pixels (so that mean is 1; all zeros without tissue)."""
        importance = frame.tissue.float()
        if self.gamma > 0:
            importance = importance * (1.0 + self.gamma * self._observed_frequency())
        mean = importance.sum() / frame.tissue.sum().clamp_min(1)
        return importance / mean.clamp_min(1e-12)

    def _observed_frequency(self) -> Tensor:
        """S [H, W]; SurgsplatError when neither `observe` nor a checkpoint gave it."""
        if self.frequency is None:
            raise SurgsplatError("the occlusion importance map is unknown: its loss was neither "
                                 "set up on the training frames nor loaded from a checkpoint "
                                 "that holds it (runs saved before checkpoints kept the map "
                                 "cannot be resumed; train them again)")
        return self.frequency

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        """Take the saved map whatever this module holds (a freshly built one holds none, which
        torch would report as an unexpected key); a checkpoint without one (saved before maps
        were kept, or with gamma 0) loads too, for evaluation, with no map."""
        saved = state_dict.get(prefix + "frequency")
        if saved is not None:
            self.frequency = torch.empty_like(saved)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

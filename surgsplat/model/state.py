"""The Gaussians at one moment as plain tensors: what components transform and the renderer draws."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from torch import Tensor


@dataclass
class GaussianState:
    """N Gaussians ready to render."""

    means: Tensor  # [N, 3] world frame, scene units
    scales: Tensor  # [N, 3] linear scales, scene units
    quats: Tensor  # [N, 4] (w, x, y, z), not normalised
    opacities: Tensor  # [N] in (0, 1)
    sh: Tensor  # [N, K, 3] spherical-harmonic colour coefficients
    sh_degree: int
    colour_gain: Tensor | None = None
    """[3] per-channel gain that components applied to the colours for this frame (the
    exposure); None = 1. Light a component adds after rasterisation is scaled by it too."""

    def replace(self, **changes: Tensor | None) -> "GaussianState":
        """A copy with some fields replaced."""
        return dataclasses.replace(self, **changes)

"""The Gaussians at one moment as plain tensors: what components transform and the renderer draws."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
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

    def replace(self, **changes: Tensor) -> "GaussianState":
        """A copy with some fields replaced."""
        return dataclasses.replace(self, **changes)

    def with_dc_offset(self, offsets: Tensor) -> "GaussianState":
        """A copy whose degree-0 SH colour coefficients have `offsets` [N, 3] added."""
        return self.replace(sh=torch.cat([self.sh[:, :1] + offsets[:, None], self.sh[:, 1:]],
                                         dim=1))

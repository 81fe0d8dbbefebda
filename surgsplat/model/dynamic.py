"""Canonical Gaussians plus a deformation field: the Gaussians of any time t as plain tensors.

The renderer takes tensors, never this module: `state_at(t)` is the seam between them.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from surgsplat.data.scene import Camera
from surgsplat.fields.deformation import DeformationField
from surgsplat.model.exposure import ExposureCurve
from surgsplat.model.gaussians import GaussianModel
from surgsplat.render.render import RenderOutput, render


@dataclass
class GaussianState:
    """The Gaussians at one time, ready to render."""

    means: Tensor  # [N, 3] camera/world space, scene units
    scales: Tensor  # [N, 3] linear scales
    quats: Tensor  # [N, 4] (w, x, y, z), not normalised
    opacities: Tensor  # [N] in (0, 1)
    sh: Tensor  # [N, K, 3] spherical-harmonic colour coefficients
    sh_degree: int


class DeformableGaussians(nn.Module):
    """Canonical Gaussians deformed over time t in [0, 1], seen through an exposure curve."""

    def __init__(self, gaussians: GaussianModel, field: DeformationField,
                 exposure: ExposureCurve):
        super().__init__()
        self.gaussians = gaussians
        self.field = field
        self.exposure = exposure

    def render(self, camera: Camera, t: float, background: Tensor | None = None,
               absgrad: Tensor | None = None, planar_depth: bool = False) -> RenderOutput:
        """The view at time t; rgb includes the exposure gain of time t."""
        out = render_state(self.state_at(t), camera, background, absgrad, planar_depth)
        out.rgb = out.rgb * self.exposure.gain(t)
        return out

    def state_at(self, t: float) -> GaussianState:
        params = self.gaussians.params
        delta = self.field(params["means"], self.gaussians.attributes, t)
        return GaussianState(
            means=params["means"] + delta.d_means,
            scales=torch.exp(params["log_scales"] + delta.d_log_scales),
            quats=params["quats"] + delta.d_quats,
            opacities=torch.sigmoid(params["opacity_logits"]),
            sh=self.gaussians.sh_coeffs(delta.d_colors),
            sh_degree=self.gaussians.sh_degree,
        )

    def canonical_state(self) -> GaussianState:
        params = self.gaussians.params
        return GaussianState(means=params["means"], scales=params["log_scales"].exp(),
                             quats=params["quats"],
                             opacities=torch.sigmoid(params["opacity_logits"]),
                             sh=self.gaussians.sh_coeffs(), sh_degree=self.gaussians.sh_degree)


def render_state(state: GaussianState, camera: Camera, background: Tensor | None = None,
                 absgrad: Tensor | None = None, planar_depth: bool = False) -> RenderOutput:
    """Render Gaussians `state` seen by `camera`: rgb [H,W,3], alpha, depth and more."""
    return render(state.means, state.scales, state.quats, state.opacities, state.sh, camera.K,
                  camera.width, camera.height, world_to_camera=camera.world_to_camera,
                  sh_degree=state.sh_degree, planar_depth=planar_depth, background=background,
                  absgrad=absgrad)


@torch.no_grad()
def render_time(model: DeformableGaussians, camera: Camera, t: float,
                background: Tensor | None = None) -> RenderOutput:
    """Render the model at time t (no gradients), e.g. for evaluation and videos."""
    return model.render(camera, t, background)

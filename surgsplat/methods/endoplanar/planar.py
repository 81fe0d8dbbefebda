"""EndoPlanar's planar Gaussians as a component (`endoplanar.txt` Section 2.3-2.4).

- Render channels: each Gaussian's camera-space normal (the axis of its smallest scale, facing
  away from the camera) and plane distance; `finish_render` intersects each pixel's ray with the
  blended plane (Eq. 5-6) and makes that unbiased depth the render's depth (`output.depth`), so
  the depth loss (Eq. 9), the metrics and the videos all use it. The blended normal map is
  `output.extras["normal"]` [H, W, 3] and the expected depth stays in
  `output.extras["expected_depth"]` [H, W].
- Loss "flatten" (Eq. 4): the mean over Gaussians of the smallest scale at the frame's time
  (scene units), driving every Gaussian towards a disc. Its gradient is proportional to that
  scale, so it is inert on discs that start flat, as the paper's (s_3 = 0). On thick Gaussians
  it also reaches the basis widths that a Gaussian-basis deformation shares across channels,
  and widens the motion curves (docs/methods/endoplanar.md gives the A/B).
- Loss "normal" (Eq. 7-8): the L1 distance between the normalised rendered normal and the normal
  of the surface the rendered depth describes (from each pixel's four neighbours), weighted by
  (1 - |grad D|)^2 of the measured depth D. The paper leaves the gradient's unit open; here it is
  the relative gradient |grad D| / D per pixel, clamped to [0, 1], so that the weight is
  unit-free (millimetres or metres alike) and falls to 0 at depth discontinuities (tool edges,
  folds). Counted pixels: tissue pixels with a measured depth and a valid depth normal. The
  sum runs in `image.normal_consistency` (fused native kernels).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from surgsplat.data.frame_memo import PerFrame
from surgsplat.data.scene import Frame
from surgsplat.image.depth import depth_gradient_magnitude
from surgsplat.methods.endoplanar.normal_consistency import normal_consistency
from surgsplat.methods.endoplanar.plane_depth import (planar_normals_and_distances,
                                                     unbiased_plane_depth)
from surgsplat.model.channels import NORMAL
from surgsplat.model.component import Component, ComponentConfig, FrameTime, RenderContext
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState


@dataclass
class PlanarConfig(ComponentConfig, kind="planar"):
    """Planar Gaussians: normal and plane-distance channels, unbiased depth, their losses."""

    edge_aware: bool = True
    """Weight the normal loss by (1 - relative measured-depth gradient)^2 (Eq. 8); False = 1."""

    def build(self) -> "PlanarGaussians":
        return PlanarGaussians(self)


class PlanarGaussians(Component):
    """See the module docstring."""
    phase = Phase.SURFACE

    def __init__(self, config: PlanarConfig):
        super().__init__()
        self.config = config
        self.normal_loss_pixels = PerFrame(self._normal_loss_pixels)  # of the data alone

    def render_channels(self, state: GaussianState, gaussians, camera,
                        when: FrameTime) -> dict[str, Tensor]:
        normals, distances = planar_normals_and_distances(
            state.means, state.scales, state.quats, camera.world_to_camera)
        return {NORMAL: normals, "plane_distance": distances}

    def finish_render(self, output, camera, when: FrameTime) -> None:
        distance = output.extras.pop("plane_distance")[..., 0]
        output.extras["expected_depth"] = output.depth
        output.depth = unbiased_plane_depth(output.extras[NORMAL], distance, camera.K)

    def loss_names(self) -> tuple[str, ...]:
        return ("flatten", "normal")

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        terms = {}
        if "flatten" in active:
            terms["flatten"] = context.state.scales.min(dim=1).values.mean()
        if "normal" in active:
            terms["normal"] = self.normal_loss(context)
        return terms

    def normal_loss(self, context: RenderContext) -> Tensor:
        """Eq. 8 over the counted pixels (see the module docstring); 0 when there are none."""
        output = context.output
        counted, edge_weight = self.normal_loss_pixels(context.frame)
        weight = edge_weight if self.config.edge_aware else None
        total, count = normal_consistency(output.depth, output.extras[NORMAL],
                                          context.camera.K, counted, weight)
        return total / count.clamp_min(1)

    @staticmethod
    def _normal_loss_pixels(frame: Frame) -> tuple[Tensor, Tensor | None]:
        """The pixels the normal loss counts, bool [H, W] (tissue, with a measured depth where
        the frame has depth), and their edge-aware weights [H, W] (None without depth)."""
        if frame.depth is None:
            return frame.tissue, None
        measured = torch.where(frame.depth > 0, frame.depth, torch.ones_like(frame.depth))
        relative = depth_gradient_magnitude(frame.depth) / measured
        return frame.tissue & (frame.depth > 0), (1.0 - relative.clamp(0.0, 1.0)) ** 2

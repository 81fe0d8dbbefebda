"""A smooth per-time exposure gain of the rendered image.

Endoscopes change exposure over time (auto-exposure, light-source power); tissue colour should
not. The gain is exp(g(t)) per colour channel, g piecewise linear in t over `knots` evenly
spaced knots, so test frames between training frames get an interpolated exposure.
As a component it scales the Gaussians' colour at each frame (`transform`), so the exposure is
part of the Gaussians of that moment (exports and viewers see it) and never touches the
background.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from surgsplat.model.capabilities import Retimable
from surgsplat.model.component import Component, ComponentConfig, FrameTime, ParamGroup, SceneInfo
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState
from surgsplat.render.sh import SH_C0


@dataclass
class ExposureConfig(ComponentConfig, kind="exposure"):
    """The exposure curve of a run."""

    knots: int = field(default=16, metadata={"range": "[0, inf)"})
    """Knots of the piecewise-linear log-gain over t in [0, 1] (0 = no exposure model)."""
    lr: float = field(default=5e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the log-gains."""
    lr_decay: float = field(default=0.1, metadata={"range": "(0, 1]"})
    """Final over initial learning rate of the log-gains (exponential decay over the run). Each
    step fits one frame, so at a constant rate the last steps still move the knots near that
    frame's time, and the curve ends wherever the last frames left it; the decay lets it settle
    (measurements: docs/methods/shared-components.md)."""

    def resolve(self, scene: SceneInfo) -> "ExposureConfig":
        """This config for the scene's clip: at most one knot per two frames."""
        return dataclasses.replace(self, knots=min(self.knots, scene.num_frames // 2))

    def build(self) -> "ExposureCurve":
        return ExposureCurve(self)


class ExposureCurve(Component):
    """Per-channel log-gain g(t), linear between `knots` evenly spaced knots; starts at 0."""
    phase = Phase.EXPOSURE
    provides = (Retimable,)

    def __init__(self, config: ExposureConfig):
        super().__init__()
        self.config = config
        self.log_gains = nn.Parameter(torch.zeros(max(config.knots, 0), 3))  # [K, 3]

    def param_groups(self) -> list[ParamGroup]:
        config = self.config
        return [ParamGroup("exposure", [self.log_gains], config.lr, config.lr * config.lr_decay)]

    def transform(self, state: GaussianState, gaussians, when: FrameTime) -> GaussianState:
        """Colours times the gain g of `when`, in SH space: every coefficient times g, and the
        degree-0 term shifted by (g - 1) 0.5 / Y_0 so that the +0.5 offset of the SH colour
        scales too (the colour's clamp at 0 commutes with a positive gain)."""
        gain = self.gain(when.time)  # [3]
        sh = state.sh * gain
        offset = torch.zeros_like(sh[:1])
        offset[0, 0] = (gain - 1.0) * (0.5 / SH_C0)
        return state.replace(sh=sh + offset)

    @torch.no_grad()
    def retime(self, gaussians, factor: float) -> None:
        """Resample the knots: knot k (at k / (K - 1)) takes the old curve at time
        k / (K - 1) / factor, the last knot's value beyond 1."""
        knots = self.log_gains.shape[0]
        if knots < 2:
            return
        times = [min(k / (knots - 1) / factor, 1.0) for k in range(knots)]
        self.log_gains.copy_(torch.stack([self.gain(t).log() for t in times]))

    def gain(self, t: float) -> Tensor:
        """[3] multiplicative gain at time t (ones without knots)."""
        knots = self.log_gains.shape[0]
        if knots == 0:
            return torch.ones(3)
        if knots == 1:
            return self.log_gains[0].exp()
        position = min(max(t, 0.0), 1.0) * (knots - 1)
        left = min(int(position), knots - 2)
        weight = position - left
        return ((1 - weight) * self.log_gains[left] + weight * self.log_gains[left + 1]).exp()

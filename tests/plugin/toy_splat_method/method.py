"""The toy method: the core's Gaussian-basis deformation and losses, plus a component of its
own that gives every Gaussian a learnable "sheen" in (0, 1), renders it as the channel `sheen`
and pulls it towards SHEEN_TARGET over the covered tissue."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.settings import LossWeight, TrainConfig
from surgsplat.model.channels import ChannelDescriptor, ChannelKind, Colormap
from surgsplat.model.component import Component, ComponentConfig, RenderContext, SetupContext
from surgsplat.model.init_points import InitConfig
from surgsplat.model.phases import Phase

SHEEN = "sheen_logit"
"""The per-Gaussian attribute: the logit of the sheen."""
SHEEN_TARGET = 0.25


@dataclass
class SheenConfig(ComponentConfig, kind="toy_sheen"):
    """A per-Gaussian sheen in (0, 1), rendered as channel "sheen"."""

    init_logit: float = 2.0
    """Initial logit of every Gaussian's sheen."""
    lr: float = 0.05
    """Adam learning rate of the logits."""

    def build(self) -> "Sheen":
        return Sheen(self)


class SheenSource:
    """The capability of rendering the channel "sheen" (what the toy's metric family and
    product look for)."""


class Sheen(Component):
    phase = Phase.LOSS
    provides = (SheenSource,)

    def __init__(self, config: SheenConfig):
        super().__init__()
        self.config = config

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        return {SHEEN: torch.full((context.points.shape[0],), self.config.init_logit)}

    def attribute_lrs(self) -> dict[str, float]:
        return {SHEEN: self.config.lr}

    def render_channels(self, state, gaussians, camera, when) -> dict[str, Tensor]:
        return {"sheen": torch.sigmoid(gaussians.params[SHEEN])}

    def channel_descriptors(self) -> tuple[ChannelDescriptor, ...]:
        return (ChannelDescriptor("sheen", ChannelKind.SCALAR, Colormap.INFERNO, (0.0, 1.0)),)

    def loss_names(self) -> tuple[str, ...]:
        return ("sheen",)

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        rendered = context.output.extras["sheen"][..., 0]
        covered = context.output.alpha.detach()
        return {"sheen": ((rendered - SHEEN_TARGET * covered) ** 2)[context.frame.tissue].mean()}


def toy() -> MethodConfig:
    """Gaussian-basis deformation, L1 + D-SSIM and depth L1, and the sheen, on few points."""
    return MethodConfig(
        name="toy",
        components={"deformation": GaussianBasisConfig(), "sheen": SheenConfig(),
                    "photometric": PhotometricConfig(), "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                "sheen": LossWeight(1.0)},
        train=TrainConfig(iterations=60),
        init=InitConfig(max_points=3000))


PRESET = Preset("toy: a method from a package outside surgsplat, with a sheen of its own", toy)

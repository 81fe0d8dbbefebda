"""PhysioSplat's co-located specular lobe as a component (`physiosplat.txt` Section 2.4, Eq. 7).

Each Gaussian has a specular albedo beta in (0, 1) (attribute `specular_albedo_logit`, beta =
sigmoid) and a roughness gamma > 0 (attribute `specular_log_roughness`); its diffuse colour is
the degree-0 SH term (the preset sets sh_degree 0). With the light at the camera, the half vector
is the view direction v, and a Gaussian adds the white lobe beta exp((n . v - 1) / gamma^2).

The normal n comes from the rendered depth (`image.pinhole.depth_normals`), so it exists per
pixel, after rasterisation: the lobe is shaded per pixel (deferred) from the alpha-blended beta
(`specular_albedo` channel: sum_i w_i beta_i, which carries the alpha_i of Eq. 7) and the
blended sharpness 1 / gamma^2 (`specular_sharpness` channel, normalised by the pixel's alpha),
and added to the rendered colour: C += beta_bar exp((n . v - 1) sharpness_bar). The depth normal
is detached, so highlights never bend the geometry; pixels without a valid depth normal get no
lobe. The lobe is white and not scaled by an exposure component.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from surgsplat.image.pinhole import depth_normals, pixel_rays
from surgsplat.model.component import Component, ComponentConfig, FrameTime, SetupContext
from surgsplat.render.render import MIN_ALPHA_FOR_DEPTH

ALBEDO_KEY = "specular_albedo_logit"
ROUGHNESS_KEY = "specular_log_roughness"


@dataclass
class SpecularConfig(ComponentConfig, kind="specular"):
    """Per-Gaussian co-located specular lobe."""

    init_albedo: float = 0.1
    """Initial beta of every Gaussian (the paper's 0.1)."""
    init_roughness: float = 0.2
    """Initial gamma: 0.2 gives sharpness 25, a lobe at 1/e where n . v = 0.96."""
    albedo_lr: float = 0.01
    """Adam learning rate of the albedo logits."""
    roughness_lr: float = 0.005
    """Adam learning rate of the log-roughness."""

    def build(self) -> "SpecularLobe":
        return SpecularLobe(self)


class SpecularLobe(Component):
    """See the module docstring."""

    def __init__(self, config: SpecularConfig):
        super().__init__()
        self.config = config

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        count = context.points.shape[0]
        albedo = math.log(self.config.init_albedo / (1.0 - self.config.init_albedo))
        return {ALBEDO_KEY: torch.full((count,), albedo),
                ROUGHNESS_KEY: torch.full((count,), math.log(self.config.init_roughness))}

    def attribute_lrs(self) -> dict[str, float]:
        return {ALBEDO_KEY: self.config.albedo_lr, ROUGHNESS_KEY: self.config.roughness_lr}

    def render_channels(self, state, gaussians, camera, when: FrameTime) -> dict[str, Tensor]:
        params = gaussians.params
        return {"specular_albedo": torch.sigmoid(params[ALBEDO_KEY]),
                "specular_sharpness": torch.exp(-2.0 * params[ROUGHNESS_KEY])}

    def finish_render(self, output, camera, when: FrameTime) -> None:
        albedo = output.extras["specular_albedo"][..., 0]  # [H, W], carries alpha
        sharpness = output.extras["specular_sharpness"][..., 0] / output.alpha.clamp_min(
            MIN_ALPHA_FOR_DEPTH)
        lobe = specular_lobe(output.depth.detach(), camera.K, albedo, sharpness)
        output.extras["specular"] = lobe[..., None]
        output.rgb = output.rgb + lobe[..., None]


def specular_lobe(depth: Tensor, K: Tensor, albedo: Tensor, sharpness: Tensor) -> Tensor:
    """[H, W] co-located lobe albedo exp((n . v - 1) sharpness) with n the normal of the depth
    map [H, W] (scene units) and v the unit direction from the surface to the camera; 0 where
    the depth normal is not valid. Differentiable in albedo and sharpness [H, W], not depth."""
    with torch.no_grad():
        normals, valid = depth_normals(depth, K)  # facing away from the camera
        height, width = depth.shape
        rays = torch.nn.functional.normalize(pixel_rays(K, width, height, depth.dtype), dim=-1)
        cosine = (normals * rays).sum(-1).clamp(0.0, 1.0)  # n_out . v, n_out = -n, v = -ray
    lobe = albedo * torch.exp((cosine - 1.0) * sharpness)
    return torch.where(valid, lobe, torch.zeros_like(lobe))

"""PhysioSplat's co-located specular lobe as a component (`physiosplat.txt` Section 2.4, Eq. 7).

Each Gaussian has a specular albedo beta in (0, 1) (attribute `specular_albedo_logit`, beta =
sigmoid) and a roughness gamma > 0 (attribute `specular_log_roughness`); its diffuse colour is
the degree-0 SH term (the preset sets sh_degree 0). With the light at the camera, the half vector
is the view direction v, and a Gaussian adds the white lobe beta exp((n . v - 1) / gamma^2).

The normal n comes from the rendered depth (as `image.pinhole.depth_normals`), so it exists per
pixel, after rasterisation; in a model of planar Gaussians (`model.planar`, the SURFACE phase,
before this one) it is their blended normal map instead, which the depth-normal loss trains.
One-pixel central differences of a raw rendered depth turn depth jitter of a small fraction of
a millimetre into normals tilted by degrees, which scatters a lobe as sharp as this one; the
depth is therefore first smoothed by the 11x11 Gaussian window (sigma 1.5 px, `image.blur`),
normalised by the blurred validity so that edges of valid depth are not pulled towards 0, which
cuts white jitter's tilt about fivefold. The lobe is shaded per pixel (deferred) from the
alpha-blended beta (`specular_albedo` channel: sum_i w_i beta_i, which carries the alpha_i of
Eq. 7) and the blended sharpness 1 / gamma^2 (`specular_sharpness` channel, normalised by the
pixel's alpha), and added to the rendered colour: C += beta_bar exp((n . v - 1) sharpness_bar).
The depth normal is detached, so highlights never bend the geometry; pixels without a valid
depth normal get no lobe. The lobe is white: it is not scaled by the frame's exposure gain as
the diffuse colours are, since scaling it cost tissue PSNR and CPU time (measured:
docs/methods/physiosplat.md, Deviations).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from surgsplat.image.blur import gaussian_blur
from surgsplat.image.pinhole import pixel_rays
from surgsplat.model.channels import NORMAL
from surgsplat.model.component import Component, ComponentConfig, FrameTime, SetupContext
from surgsplat.model.phases import Phase
from surgsplat.render.render import MIN_ALPHA_FOR_DEPTH

ALBEDO_KEY = "specular_albedo_logit"
ROUGHNESS_KEY = "specular_log_roughness"


@dataclass
class SpecularConfig(ComponentConfig, kind="specular"):
    """Per-Gaussian co-located specular lobe."""

    init_albedo: float = field(default=0.01, metadata={"range": "(0, 1)"})
    """Initial beta of every Gaussian, in (0, 1). The paper's 0.1 adds 0.1 of white to every
    surface facing the camera at the start, on top of degree-0 colours initialised from images
    that already contain the highlights (counted twice); 0.01 starts the lobe near zero and lets
    the highlights move into it (measured: docs/methods/physiosplat.md, Deviations)."""
    init_roughness: float = field(default=0.2, metadata={"range": "(0, inf)"})
    """Initial gamma: 0.2 gives sharpness 25, a lobe at 1/e where n . v = 0.96. Starting as
    sharp as the scene's highlights did not let the lobe take them, at the albedo's default
    learning rate nor at a larger one (measured: docs/methods/physiosplat.md, Deviations)."""
    albedo_lr: float = field(default=0.01, metadata={"range": "[0, inf)"})
    """Adam learning rate of the albedo logits."""
    roughness_lr: float = field(default=0.005, metadata={"range": "[0, inf)"})
    """Adam learning rate of the log-roughness."""

    def build(self) -> "SpecularLobe":
        return SpecularLobe(self)


class SpecularLobe(Component):
    """See the module docstring."""
    phase = Phase.SHADING

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
        albedo = output.extras["specular_albedo"]  # [H, W, 1], carries alpha
        sharpness = output.extras["specular_sharpness"][..., 0] / output.alpha.clamp_min(
            MIN_ALPHA_FOR_DEPTH)
        if NORMAL in output.extras:
            with torch.no_grad():
                cosine, valid = normal_view_cosine(output.extras[NORMAL], camera.K)
            lobe = shade_lobe(cosine, valid, albedo, sharpness)
        else:
            lobe = specular_lobe(output.depth, camera.K, albedo, sharpness)
        output.extras["specular"] = lobe
        output.rgb = output.rgb + lobe


def specular_lobe(depth: Tensor, K: Tensor, albedo: Tensor, sharpness: Tensor) -> Tensor:
    """[H, W, C] co-located lobe of the depth map [H, W] (scene units): `shade_lobe` with the
    normals of the smoothed depth (`smooth_depth`, `view_cosine`). Differentiable in albedo
    [H, W, C] and sharpness [H, W], not depth."""
    with torch.no_grad():
        cosine, valid = view_cosine(smooth_depth(depth), K)
    return shade_lobe(cosine, valid, albedo, sharpness)


def shade_lobe(cosine: Tensor, valid: Tensor, albedo: Tensor, sharpness: Tensor) -> Tensor:
    """[H, W, C] lobe albedo exp((n . v - 1) sharpness) from the cosine n . v [H, W] of the
    surface normal and the direction to the camera; 0 where `valid` [H, W] is False."""
    lobe = albedo * torch.exp((cosine - 1.0) * sharpness)[..., None]
    return torch.where(valid[..., None], lobe, torch.zeros_like(lobe))


def normal_view_cosine(normal: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:
    """|n . v| [H, W] for the alpha-blended normal map [H, W, 3] of planar Gaussians (camera
    space, either orientation; normalised here) and v the unit ray of each pixel centre; valid
    [H, W] where the blended normal is not degenerate."""
    height, width = normal.shape[:2]
    rays = pixel_rays(K, width, height, normal.dtype)
    length = normal.norm(dim=-1)
    cosine = (normal * rays).sum(-1).abs() / (length * rays.norm(dim=-1)).clamp_min(1e-12)
    return cosine.clamp(0.0, 1.0), length > 1e-6


def view_cosine(depth: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:
    """n . v for the normals n of `image.pinhole.depth_normals` (one-pixel central differences
    of the depth map [H, W], scene units; K [3, 3]) and v the unit direction to the camera, in
    closed form without [H, W, 3] points: with P = z r, r = ((x + 0.5 - cx) / fx,
    (y + 0.5 - cy) / fy, 1), the cross product (P_right - P_left) x (P_down - P_up) is parallel
    to m = (-fx dz_x zy, -fy dz_y zx, fx dz_x zy r_x + fy dz_y zx r_y + 2 zx zy), where dz_x,
    dz_y are the depth differences and zx, zy the means of the two neighbours across x and y,
    and m . r = 2 zx zy. Returns the cosine [H, W] in [0, 1] and valid [H, W] bool, as
    `depth_normals` defines it (interior pixels whose own and four neighbours' depths are > 0,
    with a non-degenerate normal)."""
    height, width = depth.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    rx = ((torch.arange(1, width - 1, dtype=depth.dtype) + 0.5 - cx) / fx)[None]  # [1, W-2]
    ry = ((torch.arange(1, height - 1, dtype=depth.dtype) + 0.5 - cy) / fy)[:, None]  # [H-2, 1]
    right, left = depth[1:-1, 2:], depth[1:-1, :-2]
    down, up = depth[2:, 1:-1], depth[:-2, 1:-1]
    dz_x, zx = right - left, 0.5 * (right + left)
    dz_y, zy = down - up, 0.5 * (down + up)
    mx, my = -fx * dz_x * zy, -fy * dz_y * zx
    mz = -(mx * rx + my * ry) + 2.0 * zx * zy
    length = (mx.square() + my.square() + mz.square()).sqrt()
    ray = (rx.square() + ry.square() + 1.0).sqrt()
    inner = (2.0 * zx * zy / (length * ray).clamp_min(1e-12)).clamp(0.0, 1.0)
    positive = depth > 0
    ok = (positive[1:-1, 2:] & positive[1:-1, :-2] & positive[2:, 1:-1] & positive[:-2, 1:-1]
          & positive[1:-1, 1:-1] & (length > 1e-12))
    cosine = torch.nn.functional.pad(inner, (1, 1, 1, 1))
    valid = torch.nn.functional.pad(ok, (1, 1, 1, 1))
    return cosine, valid


def smooth_depth(depth: Tensor) -> Tensor:
    """[H, W] depth (scene units, 0 = none) blurred by `image.blur.gaussian_blur` over its valid
    (> 0) pixels only: blur(depth) / blur(valid), 0 where the depth was 0."""
    valid = (depth > 0).to(depth.dtype)
    blurred = gaussian_blur(torch.stack([depth * valid, valid]))
    return torch.where(valid > 0, blurred[0] / blurred[1].clamp_min(1e-6),
                       torch.zeros_like(depth))

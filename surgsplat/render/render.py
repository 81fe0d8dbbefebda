"""`render(...)`: Gaussians in, colour, alpha, depth and any extra channels out, in one pass.

Everything is rendered as channels of one rasterisation: colour (3), camera depth (1) and the
requested per-Gaussian extras (normals, plane distances, semantic logits, ...; see planar.py for
the normal and distance channels of planar Gaussians).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from surgsplat.render.pixel_weights import PixelWeights
from surgsplat.render.project import Projection, project
from surgsplat.render.rasterize import Backend, rasterize
from surgsplat.render.sh import sh_colour

MIN_ALPHA_FOR_DEPTH = 1e-6
"""Expected depth divides by alpha clamped to at least this."""


@dataclass
class RenderOutput:
    """One rendered view; depths in the scene unit."""

    rgb: Tensor  # [H, W, 3] colour composited over the background
    alpha: Tensor  # [H, W] accumulated opacity
    depth: Tensor  # [H, W] expected camera depth of the visible surface (sum w z / alpha)
    projection: Projection  # the screen-space Gaussians (radii, means2d, ...)
    extras: dict[str, Tensor] = field(default_factory=dict)  # name -> [H, W, k], alpha-blended


class _SplitChannels(torch.autograd.Function):
    """The rasterised image [H, W, C >= 4] and alpha [H, W] split into colour [H, W, 3] (a view:
    the rasteriser composited the background), depth [H, W] = image[..., 3] / max(alpha,
    MIN_ALPHA_FOR_DEPTH), and the extra channel groups (views of image[..., 4:], `sizes` channels
    each). The backward is written out and fills one [H, W, C] gradient, where autograd's chain
    would make a zero-filled [H, W, C] gradient per output and sum them, and run the division's
    two terms; an output the loss does not use costs nothing."""

    @staticmethod
    def forward(ctx, image: Tensor, alpha: Tensor, sizes: tuple[int, ...]) -> tuple[Tensor, ...]:
        ctx.set_materialize_grads(False)
        clamped = alpha.clamp_min(MIN_ALPHA_FOR_DEPTH)
        depth = image[..., 3] / clamped
        ctx.save_for_backward(alpha, clamped, depth)
        ctx.channels, ctx.sizes = image.shape[-1], sizes
        offsets = [4 + sum(sizes[:i]) for i in range(len(sizes))]
        extras = [image[..., offset:offset + k] for offset, k in zip(offsets, sizes)]
        return image[..., :3], depth, *extras

    @staticmethod
    def backward(ctx, grad_colour: Tensor | None, grad_depth: Tensor | None,
                 *grad_extras: Tensor | None):
        alpha, clamped, depth = ctx.saved_tensors
        grad_image = alpha.new_zeros(*alpha.shape, ctx.channels)
        grad_alpha = None
        if grad_colour is not None:
            grad_image[..., :3] = grad_colour
        if grad_depth is not None:
            grad_depth_raw = grad_depth / clamped
            grad_image[..., 3] = grad_depth_raw
            # the clamp passes no gradient to alpha where alpha <= MIN_ALPHA_FOR_DEPTH
            grad_alpha = -(grad_depth_raw * depth).masked_fill_(alpha <= MIN_ALPHA_FOR_DEPTH, 0.0)
        offset = 4
        for k, grad in zip(ctx.sizes, grad_extras):
            if grad is not None:
                grad_image[..., offset:offset + k] = grad
            offset += k
        return grad_image, grad_alpha, None


def render(means: Tensor, scales: Tensor, quats: Tensor, opacities: Tensor, colors: Tensor,
           K: Tensor, width: int, height: int, world_to_camera: Tensor | None = None,
           sh_degree: int | None = None, extras: dict[str, Tensor] | None = None,
           background: Tensor | None = None,
           absgrad: Tensor | None = None, gradient_weights: PixelWeights | None = None,
           backend: Backend = "auto", near: float = 0.01) -> RenderOutput:
    """Render Gaussians: means [N,3], scales [N,3] (linear), quats [N,4] (w,x,y,z), opacities [N],
    colors [N,3] RGB, or [N,K,3] SH coefficients when sh_degree is given.

    extras: name -> [N] or [N,k] per-Gaussian values to alpha-blend (normals, semantic logits, ...);
    they come back in RenderOutput.extras as [H, W, k].
    background [3]: colour behind the Gaussians (black when None). absgrad [N],
    gradient_weights: see rasterize (the weights scale every channel's gradients).
    """
    projection = project(means, scales, quats, K, width, height, world_to_camera, near=near,
                         backend=backend)
    if sh_degree is None:
        rgb = colors
    else:
        rgb = sh_colour(sh_degree, colors, means, world_to_camera, backend=backend)
    channels = [rgb, projection.depths[:, None]]
    extras = extras or {}
    for value in extras.values():
        channels.append(value.reshape(value.shape[0], -1))
    features = torch.cat(channels, dim=1)
    if background is not None:  # behind the colour only: depth and extras fade to 0
        background = torch.cat([background.to(features), features.new_zeros(features.shape[1] - 3)])
    image, alpha = rasterize(projection.means2d, projection.conics, opacities, features,
                             projection.depths, projection.radii, width, height,
                             absgrad=absgrad, background=background, gradient_weights=gradient_weights,
                             backend=backend)

    sizes = tuple(value.reshape(value.shape[0], -1).shape[1] for value in extras.values())
    color, depth, *extra_images = _SplitChannels.apply(image, alpha, sizes)
    out = RenderOutput(rgb=color, alpha=alpha, depth=depth, projection=projection)
    out.extras.update(zip(extras, extra_images))
    return out

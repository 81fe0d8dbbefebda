"""A render's channel as an image, as its descriptor says (`model.channels`): what videos, the
viewer and the report show of a render.

- colour: the values in [0, 1] as they are;
- normal: the usual normal-map colours (`export.video.colorize_normals`); the base `normal`
  channel is the render's surface normals (`eval.normals.surface_normals`), any other one the
  rendered normal map made unit;
- scalar and probability: the colour map over the channel's range. A scalar channel whose
  descriptor leaves the range to the data spans the 1st to 99th percentile of its values over
  the covered pixels of the render shown, unless the caller fixes the range (a video fixes it
  once for all its frames; the report takes the depth's from the frame's measured depth).
"""

from __future__ import annotations

import cv2
import numpy as np
from torch import Tensor

from surgsplat.errors import SurgsplatError
from surgsplat.eval.normals import MIN_ALPHA, rendered_normals, surface_normals
from surgsplat.export.video import colorize_depth, colorize_normals, to_uint8
from surgsplat.model.channels import DEPTH, NORMAL, RGB, ChannelDescriptor, ChannelKind, Colormap
from surgsplat.render.render import RenderOutput

PERCENTILES = (0.01, 0.99)
"""The quantiles a range left to the data spans."""


def percentile_range(values: Tensor) -> tuple[float, float]:
    """(low, high): the PERCENTILES of values [M]; (0, 1) when there are none."""
    if values.numel() == 0:
        return 0.0, 1.0
    return float(values.quantile(PERCENTILES[0])), float(values.quantile(PERCENTILES[1]))


def channel_values(output: RenderOutput, channel: ChannelDescriptor) -> Tensor:
    """[H, W, k] the values of `channel` in `output` (the colour, the depth, or an extra);
    SurgsplatError when the render lacks a channel its method declares."""
    if channel.name == RGB:
        return output.rgb
    if channel.name == DEPTH:
        return output.depth[..., None]
    if channel.name not in output.extras:
        raise SurgsplatError(f"the render has no {channel.name!r} channel, which a component of "
                             "its method declares")
    return output.extras[channel.name]


def display_range(output: RenderOutput, channel: ChannelDescriptor) -> tuple[float, float]:
    """(low, high) values the colour map of a scalar or probability `channel` spans in
    `output`: [0, 1] for a probability, else the descriptor's range, else the percentile range
    of the values over the pixels covered (alpha above MIN_ALPHA)."""
    if channel.kind is ChannelKind.PROBABILITY:
        return 0.0, 1.0
    if channel.value_range is not None:
        return channel.value_range
    return percentile_range(channel_values(output, channel)[..., 0][output.alpha > MIN_ALPHA])


def colormap_image(values: np.ndarray, colormap: Colormap, low: float,
                   high: float) -> np.ndarray:
    """[H, W] values -> uint8 RGB [H, W, 3] through `colormap` over [low, high]."""
    if colormap is Colormap.DEPTH:
        return colorize_depth(values, low, high)
    grey = to_uint8(np.clip((values - low) / max(high - low, 1e-9), 0.0, 1.0))
    if colormap is Colormap.GRAY:
        return np.repeat(grey[..., None], 3, axis=-1)
    return cv2.applyColorMap(grey, cv2.COLORMAP_INFERNO)[..., ::-1]


def channel_image(output: RenderOutput, channel: ChannelDescriptor, K: Tensor,
                  value_range: tuple[float, float] | None = None) -> np.ndarray:
    """uint8 RGB [H, W, 3]: `channel` of `output` (rendered with intrinsics K [3, 3]) as its
    descriptor says; `value_range` (low, high), when given, replaces a scalar channel's own
    range (see the module docstring)."""
    if channel.kind is ChannelKind.COLOUR:
        return to_uint8(channel_values(output, channel).clamp(0, 1).numpy())
    if channel.kind is ChannelKind.NORMAL:
        normals, valid = (surface_normals(output, K)[:2] if channel.name == NORMAL else
                          rendered_normals(channel_values(output, channel), output.alpha))
        return colorize_normals(normals.numpy(), valid.numpy())
    low, high = value_range or display_range(output, channel)
    return colormap_image(channel_values(output, channel)[..., 0].numpy(), channel.colormap,
                          low, high)

"""What a render shows, channel by channel: each channel's descriptor (its name, its kind and how
to show it), so that videos, the viewer and the report list a model's channels without naming
them.

A render always has the base channels: its colour (`rgb`), its depth (`depth`, the scene's
unit) and the normals of its surface (`normal`: a rendered normal map where a component renders
one, else the normals of the rendered depth). A component adds the channels of
`RenderOutput.extras` it wants shown by declaring them (`Component.channel_descriptors`).

Kinds, and how each is shown:
- colour: [H, W, 3] RGB in [0, 1], shown as it is;
- normal: [H, W, 3] camera-space normals, shown in the usual normal-map colours;
- scalar: [H, W, 1], shown through its colour map over its value range: a fixed range, or
  (None) the 1st to 99th percentile of its values over the covered pixels;
- probability: [H, W, 1] in [0, 1], shown through its colour map over [0, 1].

Channels an intrinsic decomposition renders go by standard names (`REFLECTANCE`,
`ILLUMINATION`), under which the decomposition metrics find them.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class ChannelKind(Enum):
    """What the values of a channel are; see the module docstring."""

    COLOUR = "colour"
    SCALAR = "scalar"
    NORMAL = "normal"
    PROBABILITY = "probability"


class Colormap(Enum):
    """How a scalar or probability channel's values, scaled to [0, 1] over its range, become
    colours."""

    GRAY = "gray"  # black (low) to white (high)
    INFERNO = "inferno"  # black through purple and orange to yellow (high)
    DEPTH = "depth"  # turbo, near (low) red to far (high) blue; values <= 0 (no depth) black


@dataclass(frozen=True)
class ChannelDescriptor:
    """One channel of a render and how to show it."""

    name: str
    """"rgb", "depth", "normal", or the key of `RenderOutput.extras` the channel is in."""
    kind: ChannelKind
    colormap: Colormap = Colormap.GRAY
    """Scalar and probability channels: their colour map (other kinds: unused)."""
    value_range: tuple[float, float] | None = None
    """Scalar channels: the (low, high) values the colour map spans; None: the 1st to 99th
    percentile of the channel's values over the covered pixels (other kinds: unused)."""


RGB = "rgb"
DEPTH = "depth"
NORMAL = "normal"
BASE_CHANNELS = (ChannelDescriptor(RGB, ChannelKind.COLOUR),
                 ChannelDescriptor(DEPTH, ChannelKind.SCALAR, Colormap.DEPTH),
                 ChannelDescriptor(NORMAL, ChannelKind.NORMAL))
"""The channels of every render."""

REFLECTANCE = "reflectance"
"""Standard name of a decomposition's reflectance channel: colour [H, W, 3]."""
ILLUMINATION = "illumination"
"""Standard name of a decomposition's illumination channel: scalar [H, W, 1] in [0, 1]."""
TOOL_PROBABILITY = "tool_probability"
"""Standard name of the channel of a model that separates the tool: the rendered probability
that a pixel shows tool, [H, W, 1] in [0, 1]."""
OBSERVED = "observed"
"""Standard name of the channel that tells observed from filled tissue: the rendered share of a
pixel's opacity that comes from Gaussians some frame observed, [H, W, 1] in [0, 1] (0 where a
model filled tissue no frame shows, and where nothing is rendered)."""

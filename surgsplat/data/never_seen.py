"""Tissue that no frame shows: where a tool covers the same place in every frame of a static
camera, and that place's colour and depth continued smoothly from what the frames show around
it.

The fill is the Navier-Stokes inpainting of the mean observed tissue colour and depth
(`cv2.inpaint`, INPAINT_NS): it carries the values and their level lines in from the hole's rim,
the smoothest continuation the rim allows. It is a guess, never an observation; a model that
uses it marks it (the tool field's `observed` channel).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import Tensor

from surgsplat.data.scene import Frame

INPAINT_RADIUS_PX = 5
"""Neighbourhood of each filled pixel that the inpainting draws on."""


def never_seen_pixels(frames: list[Frame]) -> Tensor | None:
    """[H, W] bool: the pixels that no frame of `frames` shows as tissue, inside the first
    frame's field of view; None when the frames' cameras differ (a pixel is then no fixed place
    of the tissue) or there are none."""
    if not frames:
        return None
    pose = frames[0].camera.world_to_camera
    if any(not torch.allclose(frame.camera.world_to_camera, pose) for frame in frames[1:]):
        return None
    seen = torch.zeros_like(frames[0].fov)
    for frame in frames:
        seen |= frame.tissue
    return frames[0].fov & ~seen


@dataclass(frozen=True)
class FilledTissue:
    """The tissue of a static camera's view with its never-seen pixels filled."""

    colour: Tensor
    """[H, W, 3] RGB in [0, 1]: the mean over the frames that show each pixel as tissue, filled
    across the never-seen pixels."""
    depth: Tensor
    """[H, W] the mean observed depth likewise (0 where neither observed nor filled)."""
    never_seen: Tensor
    """[H, W] bool: the filled pixels."""


def fill_never_seen(frames: list[Frame], depths: dict[int, Tensor]) -> FilledTissue | None:
    """The frames' tissue with what none of them shows filled (see the module docstring);
    depths: frame index -> [H, W] depth to use (the frame's, or a stand-in without one). None
    when there is nothing to fill or the camera moves."""
    hole = never_seen_pixels(frames)
    if hole is None or not hole.any():
        return None
    height, width = hole.shape
    colour_sum, colour_count = torch.zeros(height, width, 3), torch.zeros(height, width)
    depth_sum, depth_count = torch.zeros(height, width), torch.zeros(height, width)
    for frame in frames:
        tissue = frame.tissue
        colour_sum[tissue] += frame.image[tissue]
        colour_count += tissue.float()
        with_depth = tissue & (depths[frame.index] > 0)
        depth_sum[with_depth] += depths[frame.index][with_depth]
        depth_count += with_depth.float()
    colour = colour_sum / colour_count.clamp_min(1.0)[..., None]
    depth = depth_sum / depth_count.clamp_min(1.0)
    colour_hole = (colour_count == 0).numpy().astype(np.uint8)
    depth_hole = (depth_count == 0).numpy().astype(np.uint8)
    colour_u8 = (colour.clamp(0, 1) * 255).round().byte().numpy()
    filled_colour = cv2.inpaint(colour_u8, colour_hole, INPAINT_RADIUS_PX, cv2.INPAINT_NS)
    filled_depth = cv2.inpaint(depth.numpy().astype(np.float32), depth_hole, INPAINT_RADIUS_PX,
                               cv2.INPAINT_NS)
    return FilledTissue(colour=torch.from_numpy(filled_colour).float() / 255.0,
                        depth=torch.from_numpy(filled_depth).float(), never_seen=hole)

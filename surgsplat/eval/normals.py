"""Surface normals of a render and their angular error against ground truth.

A method that renders a normal channel (planar Gaussians) gives its normal map directly; for any
other method the normals are those of the surface its rendered depth describes (cross products
of the four neighbouring back-projected points, `image.pinhole.depth_normals`). Both are
camera-space and oriented away from the camera.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from surgsplat.image.pinhole import depth_normals
from surgsplat.model.channels import NORMAL
from surgsplat.render.render import RenderOutput

MIN_ALPHA = 0.5
"""Pixels less covered than this have no rendered surface."""


def surface_normals(output: RenderOutput, K: Tensor) -> tuple[Tensor, Tensor, str]:
    """Unit camera-space normals [H, W, 3], valid [H, W] bool, and their source ("rendered"
    or "depth") of a render with intrinsics K [3, 3]."""
    if NORMAL in output.extras:
        return (*rendered_normals(output.extras[NORMAL], output.alpha), "rendered")
    normals, valid = depth_normals(output.depth, K)
    return normals, valid & (output.alpha > MIN_ALPHA), "depth"


def rendered_normals(normals: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor]:
    """A rendered (alpha-blended) normal map [H, W, 3] made unit, and valid [H, W] bool: the
    pixels covered (alpha [H, W] above MIN_ALPHA) where the blend is not zero."""
    length = normals.norm(dim=-1)
    unit = normals / length.clamp_min(1e-12)[..., None]
    return unit, (alpha > MIN_ALPHA) & (length > 1e-6)


def normal_angle_deg(normals: Tensor, gt_normals: Tensor, mask: Tensor) -> Tensor:
    """[M] angles in degrees between unit normals [H, W, 3] and gt normals [H, W, 3] at the
    pixels of mask [H, W] bool, orientation-free (the angle between the two lines, in [0, 90]),
    as ground truth and renders may orient normals oppositely."""
    cosine = (normals[mask].double() * gt_normals[mask].double()).sum(-1).abs().clamp(max=1.0)
    return torch.acos(cosine) * (180.0 / math.pi)

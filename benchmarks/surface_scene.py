"""A synthetic tissue-like Gaussian layout for render benchmarks: Gaussians back-projected from
a smooth, wavy depth map (60-100 mm) seen by the EndoNeRF camera, flattened along the surface
normal and sized to tile the surface with some overlap, as a trained tissue model looks."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

ENDONERF_FOCAL = 569.4682
"""Focal length in pixels of the EndoNeRF camera (640x512)."""


@dataclass
class SurfaceGaussians:
    means: Tensor  # [N, 3] mm, camera space
    scales: Tensor  # [N, 3] mm
    quats: Tensor  # [N, 4]
    opacities: Tensor  # [N]
    features: Tensor  # [N, C]
    K: Tensor  # [3, 3]
    width: int
    height: int


def tissue_depth(u: Tensor, v: Tensor, width: int, height: int) -> Tensor:
    """Depth in mm of a wavy tissue surface at pixel coordinates (u, v)."""
    x, y = u / width, v / height
    return (80.0 + 12.0 * torch.sin(2.1 * math.pi * x + 0.4) * torch.cos(1.7 * math.pi * y)
            + 6.0 * (x - 0.5) * (y + 0.3))


def surface_gaussians(num: int, channels: int = 3, width: int = 640, height: int = 512,
                      focal: float = ENDONERF_FOCAL, seed: int = 0) -> SurfaceGaussians:
    """`num` Gaussians covering the image, back-projected from `tissue_depth`."""
    generator = torch.Generator().manual_seed(seed)
    u = torch.rand(num, generator=generator) * width
    v = torch.rand(num, generator=generator) * height
    z = tissue_depth(u, v, width, height)
    K = torch.tensor([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1.0]])
    means = torch.stack([(u - width / 2) / focal * z, (v - height / 2) / focal * z, z], dim=1)
    spacing_px = math.sqrt(width * height / num)
    in_plane = 1.2 * spacing_px * z / focal * (0.7 + 0.6 * torch.rand(num, generator=generator))
    scales = torch.stack([in_plane, in_plane * (0.6 + 0.4 * torch.rand(num, generator=generator)),
                          0.05 * in_plane], dim=1)
    quats = torch.cat([torch.ones(num, 1), 0.15 * torch.randn(num, 3, generator=generator)], 1)
    opacities = 0.5 + 0.5 * torch.rand(num, generator=generator)
    features = torch.rand(num, channels, generator=generator)
    return SurfaceGaussians(means, scales, quats, opacities, features, K, width, height)

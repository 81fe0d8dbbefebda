"""Random screen-space scenes shared by the render tests."""

from __future__ import annotations

import pytest
import torch

from surgsplat.render.project import project


def random_scene(num: int, width: int, height: int, channels: int = 3, seed: int = 0,
                 dtype: torch.dtype = torch.float32, scale: float = 0.12):
    """Projected random Gaussians in front of a 40 px focal camera: a dict of rasterize inputs."""
    generator = torch.Generator().manual_seed(seed)
    means = torch.randn(num, 3, generator=generator, dtype=torch.float64) * 0.6
    means[:, 2] += 4.0
    scales = torch.rand(num, 3, generator=generator, dtype=torch.float64) * scale + 0.02
    quats = torch.randn(num, 4, generator=generator, dtype=torch.float64)
    K = torch.tensor([[40.0, 0, width / 2], [0, 40.0, height / 2], [0, 0, 1]], dtype=torch.float64)
    proj = project(means, scales, quats, K, width, height)
    return {
        "means2d": proj.means2d.to(dtype),
        "conics": proj.conics.to(dtype),
        "opacities": (torch.rand(num, generator=generator, dtype=torch.float64) * 0.9 + 0.05).to(dtype),
        "features": torch.rand(num, channels, generator=generator, dtype=torch.float64).to(dtype),
        "depths": proj.depths.to(dtype),
        "radii": proj.radii,
        "width": width,
        "height": height,
    }


@pytest.fixture
def scene_factory():
    return random_scene

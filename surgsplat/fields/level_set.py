"""The zero level set of a signed distance field as a triangle mesh (marching cubes).

The one extraction of a surface from a field: the mesh export (`surgsplat.export.mesh`) and the
components that anchor Gaussians on a mesh both call `marching_cubes`. scikit-image and trimesh
come with the optional extra `mesh`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from surgsplat.errors import SurgsplatError


def mesh_library(name: str):
    """Import scikit-image's or trimesh's module `name`, which the optional extra `mesh`
    installs; SurgsplatError saying so when it is missing."""
    try:
        return importlib.import_module(name)
    except ImportError as err:
        raise SurgsplatError(f"meshes need scikit-image and trimesh ({name} is missing): "
                             "pip install 'surgsplat[mesh]'") from err


def marching_cubes(signed_distance: Callable[[Tensor], Tensor], box: Tensor,
                   resolution: int, chunk: int = 1 << 18) -> tuple[np.ndarray, np.ndarray, float]:
    """The zero level set of `signed_distance` ([P, 3] -> [P], scene units) over box [2, 3]
    (lo, hi), sampled with cubic cells, `resolution` of them along the box's longest side.
    Returns vertices [V, 3] float64, faces [F, 3] int64 and the cell size."""
    measure = mesh_library("skimage.measure")
    lo, hi = box[0].double(), box[1].double()
    cell = float((hi - lo).max()) / resolution
    counts = [max(2, int(np.ceil(float(side) / cell)) + 1) for side in hi - lo]
    axes = [lo[i] + torch.arange(counts[i], dtype=torch.float64) * cell for i in range(3)]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3).float()
    with torch.no_grad():
        values = torch.cat([signed_distance(part) for part in grid.split(chunk)]).numpy()
    volume = values.reshape(counts)
    if not (volume.min() < 0 < volume.max()):
        raise SurgsplatError("the signed distance field has no surface inside its box "
                             f"(values in [{volume.min():.3g}, {volume.max():.3g}])")
    vertices, faces, _, _ = measure.marching_cubes(volume, level=0.0, spacing=(cell,) * 3)
    return vertices + lo.numpy(), faces.astype(np.int64), cell

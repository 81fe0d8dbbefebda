"""Canonical Gaussians: every per-Gaussian tensor in two dicts of [N, ...] rows.

The learnable ones (geometry, appearance and the components' per-Gaussian attributes, e.g. a
deformation field's) are the parameters of `params`; the non-learnable ones (the components'
per-Gaussian buffers, e.g. the face a Gaussian is anchored to) are the buffers of `buffer_dict`.
Keeping them all as rows of one model is what lets the densification strategy clone, split and
prune Gaussians with one mechanism.
"""

from __future__ import annotations

import math
from collections.abc import ItemsView, Iterator, Mapping
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from surgsplat.render.sh import SH_C0

GEOMETRY_KEYS = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")


@dataclass
class GaussianConfig:
    """How canonical Gaussians are created from an initial point cloud."""

    sh_degree: int = field(default=1, metadata={"range": "[0, 3]"})
    """Degree of the view-dependent spherical-harmonic colour (0 = diffuse colour only)."""
    init_opacity: float = field(default=0.3, metadata={"range": "(0, 1)"})
    """Opacity of every Gaussian at initialisation."""
    init_scale_factor: float = field(default=0.8, metadata={"range": "(0, inf)"})
    """Initial scale = this x the mean distance to the 3 nearest neighbours."""
    init_thickness: float = field(default=1.0, metadata={"range": "(0, 1]"})
    """Initial third scale axis (the camera's z: tissue faces the camera) as a fraction of the
    other two; 1 = isotropic, small = flat discs, as planar Gaussians start."""
    max_gaussians: int = field(default=150_000, metadata={"range": "[8, inf)"})
    """Hard cap on the number of Gaussians (densification stops adding beyond it)."""
    max_per_pixel: float = field(default=0.25, metadata={"range": "[0.05, inf)"})
    """Also cap the count at this many Gaussians per image pixel (keeps small scenes small)."""

    def cap(self, width: int, height: int) -> int:
        """The Gaussian budget of a width x height scene."""
        return min(self.max_gaussians, int(self.max_per_pixel * width * height))


def rgb_to_sh_dc(rgb: Tensor) -> Tensor:
    """[N, 3] colour in [0, 1] -> [N, 3] degree-0 SH coefficients."""
    return (rgb - 0.5) / SH_C0


def num_sh_coeffs(degree: int) -> int:
    return (degree + 1) ** 2


def knn_mean_distance(points: Tensor, k: int = 3, chunk: int = 4096) -> Tensor:
    """[N, 3] -> [N] mean distance to the k nearest other points (exact, via a KD-tree)."""
    from scipy.spatial import cKDTree

    array = points.detach().double().cpu().numpy()
    distances, _ = cKDTree(array).query(array, k=k + 1, workers=torch.get_num_threads())
    return torch.from_numpy(distances[:, 1:].mean(axis=1)).to(points)


class BufferDict(nn.Module):
    """Named tensors held as buffers (in `state_dict`, moved by `.to`), read and replaced like
    the values of a dict."""

    def __init__(self, tensors: Mapping[str, Tensor]):
        super().__init__()
        for name, tensor in tensors.items():
            self.register_buffer(name, tensor)

    def __getitem__(self, name: str) -> Tensor:
        return self._buffers[name]

    def __setitem__(self, name: str, tensor: Tensor) -> None:
        self.register_buffer(name, tensor)

    def __contains__(self, name: object) -> bool:
        return name in self._buffers

    def __iter__(self) -> Iterator[str]:
        return iter(self._buffers)

    def __len__(self) -> int:
        return len(self._buffers)

    def items(self) -> ItemsView[str, Tensor]:
        return self._buffers.items()


class GaussianModel(nn.Module):
    """N canonical Gaussians.

    params holds, each [N, ...]: means [N,3] (scene units), log_scales [N,3], quats [N,4]
    (w,x,y,z, unnormalised), opacity_logits [N], sh_dc [N,3], sh_rest [N,K-1,3] with
    K = (sh_degree+1)^2, plus the components' learnable per-Gaussian attributes; buffer_dict
    holds the components' non-learnable per-Gaussian tensors, each [N, ...].
    """

    def __init__(self, params: dict[str, Tensor], sh_degree: int,
                 buffers: dict[str, Tensor] | None = None):
        super().__init__()
        buffers = buffers or {}
        sizes = {name: value.shape[0] for name, value in {**params, **buffers}.items()}
        if len(set(sizes.values())) != 1 or len(sizes) != len(params) + len(buffers):
            raise ValueError(f"per-Gaussian tensors disagree on N or share a name: {sizes}, "
                             f"buffers {sorted(buffers)}")
        self.sh_degree = sh_degree
        self.params = nn.ParameterDict({k: nn.Parameter(v) for k, v in params.items()})
        self.buffer_dict = BufferDict(buffers)

    @classmethod
    def from_points(cls, points: Tensor, colors: Tensor, config: GaussianConfig,
                    attributes: dict[str, Tensor] | None = None,
                    buffers: dict[str, Tensor] | None = None) -> "GaussianModel":
        """points [N,3], colors [N,3] in [0,1]; attributes: extra learnable per-Gaussian
        tensors [N, ...]; buffers: non-learnable per-Gaussian tensors [N, ...]."""
        n = points.shape[0]
        scale = knn_mean_distance(points).clamp_min(1e-4) * config.init_scale_factor
        quats = torch.zeros(n, 4)
        quats[:, 0] = 1.0
        opacity = torch.full((n,), config.init_opacity)
        params = {
            "means": points.float().clone(),
            "log_scales": (scale.log()[:, None].repeat(1, 3)
                           + torch.tensor([0.0, 0.0, math.log(config.init_thickness)])).float(),
            "quats": quats,
            "opacity_logits": torch.logit(opacity),
            "sh_dc": rgb_to_sh_dc(colors.float()),
            "sh_rest": torch.zeros(n, num_sh_coeffs(config.sh_degree) - 1, 3),
        }
        params.update(attributes or {})
        return cls(params, config.sh_degree, buffers)

    @property
    def num_gaussians(self) -> int:
        return self.params["means"].shape[0]

    def per_gaussian(self) -> dict[str, Tensor]:
        """Every per-Gaussian tensor [N, ...] by name: the parameters, then the buffers."""
        return {**dict(self.params.items()), **dict(self.buffer_dict.items())}

    @property
    def attributes(self) -> dict[str, Tensor]:
        """Per-Gaussian tensors that are not geometry or appearance (deformation-field state)."""
        return {k: v for k, v in self.params.items() if k not in GEOMETRY_KEYS}

    def sh_coeffs(self, dc_offset: Tensor | None = None) -> Tensor:
        """[N, K, 3] SH coefficients; dc_offset [N, 3] is added to the degree-0 term."""
        dc = self.params["sh_dc"] if dc_offset is None else self.params["sh_dc"] + dc_offset
        return torch.cat([dc[:, None, :], self.params["sh_rest"]], dim=1)

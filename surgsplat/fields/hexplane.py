"""HexPlane deformation field (K-Planes / 4DGS).

Six learnable feature planes per scale: three spatial (xy, xz, yz) and three spatio-temporal
(xt, yt, zt). A Gaussian's canonical mean, normalised to [-1, 1] by the bounds (`set_bounds`,
points outside are clamped to the border), and the time t in [0, 1] are looked up bilinearly in
each plane (grid_sample, align_corners=True); the six C-dimensional features of one scale are
multiplied elementwise (Hadamard product) and the scales concatenated. A small MLP turns the
[N, C x scales] features into the deformation channels (means, log-scales, quaternion, colour).

The lookup runs in the native kernel (csrc/hexplane, forward and backward fused over the six
planes) for float32 CPU tensors when it is built; `_sample` with grid_sample is the reference.

Initialisation as in K-Planes/4DGS: spatial planes uniform(0.1, 0.5), spatio-temporal planes 1
(so time initially leaves the features unchanged), and the MLP's last layer zero, so that the
field starts as the identity (all offsets zero).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from surgsplat.errors import SurgsplatError
from surgsplat.fields.deformation import (Deformation, DeformationField, num_channels,
                                          time_capacity)
from surgsplat.model.component import ComponentConfig, ParamGroup, SceneInfo
from surgsplat.render.native import Backend, native_module, resolve_backend

SPATIAL_AXES = ((0, 1), (0, 2), (1, 2))
"""Axes (x=0, y=1, z=2) of the spatial planes xy, xz, yz: (plane width axis, plane height axis)."""


@dataclass
class HexPlaneConfig(ComponentConfig, kind="hexplane"):
    """Resolutions, MLP size and learning rates of a HexPlane field."""

    base_resolution: int = field(default=32, metadata={"range": "[2, inf)"})
    """Spatial resolution (cells per axis) of the coarsest scale."""
    multires: tuple[int, ...] = field(default=(1, 2), metadata={"range": "[1, inf)"})
    """Spatial resolution multipliers, one feature scale each."""
    max_resolution: int = field(default=64, metadata={"range": "[2, 1024]",
                                                       "at_least": "base_resolution"})
    """Upper limit of any scale's spatial resolution, at least base_resolution. Two scales up
    to 64 cells: a third, finer scale costs more CPU time than its small gain in fidelity is
    worth (measurements: docs/methods/shared-components.md)."""
    time_resolution: int = field(default=25, metadata={"range": "[2, inf)"})
    """Cells along time of the spatio-temporal planes for a short clip (at most half the frame
    count)."""
    long_clip_frames_per_cell: int = field(default=10, metadata={"range": "[1, inf)"})
    """Clips longer than 10 x time_resolution frames get one time cell per this many frames
    (the planes' memory grows with it; the cost per Gaussian does not)."""
    max_time_resolution: int = field(default=300, metadata={"range": "[2, inf)",
                                                            "at_least": "time_resolution"})
    """Upper limit of the time cells of a long clip, at least time_resolution."""
    feature_dim: int = field(default=32, metadata={"range": "[1, inf)"})
    """Feature channels C of every plane."""
    mlp_width: int = field(default=64, metadata={"range": "[1, inf)"})
    """Width of the MLP's hidden layers."""
    mlp_depth: int = field(default=1, metadata={"range": "[1, inf)"})
    """Number of hidden layers of the MLP (each linear + ReLU)."""
    grid_lr: float = field(default=1.6e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the spatial feature planes (xy, xz, yz)."""
    time_grid_lr: float = field(default=1.6e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the spatio-temporal feature planes (xt, yt, zt), where the motion
    is: they start at 1, leaving the spatial features unchanged, and a time row is moved only by
    the frames near its time."""
    mlp_lr: float = field(default=1.6e-4, metadata={"range": "[0, inf)"})
    """Adam learning rate of the MLP."""
    lr_decay: float = field(default=0.1, metadata={"range": "(0, 1]"})
    """Final over initial learning rate of the planes (both kinds) and the MLP (exponential decay
    over the run, as 4DGS decays its own). Each step fits one frame, so at a constant rate the
    last steps still move the shared planes, and the field stops wherever the last frames left
    it: sub-pixel offsets that differ from seed to seed. A much stronger decay (0.01) stops the
    field before it has fitted the motion. Measurements: docs/methods/shared-components.md."""
    deform_color: bool = False
    """Also deform the SH DC colour."""
    volume_samples: int = field(default=0, metadata={"range": "[0, inf)"})
    """Gaussians sampled per step for the volume-preservation loss "volume"
    (`DeformationField.volume_loss`); 0 = the field offers no such loss."""
    volume_step_cells: float = field(default=0.5, metadata={"range": "(0, inf)"})
    """Central-difference step of that loss, in cells of the finest spatial plane."""

    def resolve(self, scene: SceneInfo) -> "HexPlaneConfig":
        """This config for the scene's clip: time resolution at most half the frame count (as
        4DGS chooses it), so held-out times are interpolated, not memorised;
        growing with a long clip (`time_capacity`)."""
        return dataclasses.replace(self, time_resolution=time_capacity(
            scene.num_frames, self.time_resolution, self.long_clip_frames_per_cell,
            self.max_time_resolution))

    def build(self) -> "HexPlaneField":
        return HexPlaneField(self)


class HexPlaneField(DeformationField):
    """spatial_planes[s]: [3, C, R_s, R_s] (xy, xz, yz; height axis = second axis of the pair);
    time_planes[s]: [3, C, T, R_s] (xt, yt, zt; height = time, width = x, y or z)."""

    def __init__(self, config: HexPlaneConfig):
        super().__init__()
        if config.base_resolution < 2 or config.time_resolution < 2 or not config.multires:
            raise SurgsplatError("hexplane needs base_resolution >= 2, time_resolution >= 2 and "
                                 "at least one multires scale")
        if config.mlp_depth < 1:
            raise SurgsplatError(f"hexplane mlp_depth must be >= 1, got {config.mlp_depth}")
        self.config = config
        channels = config.feature_dim
        self.spatial_planes = nn.ParameterList()
        self.time_planes = nn.ParameterList()
        for multiplier in config.multires:
            resolution = min(config.base_resolution * multiplier, config.max_resolution)
            spatial = torch.empty(3, channels, resolution, resolution).uniform_(0.1, 0.5)
            self.spatial_planes.append(nn.Parameter(spatial))
            self.time_planes.append(
                nn.Parameter(torch.ones(3, channels, config.time_resolution, resolution)))
        layers: list[nn.Module] = [nn.Linear(channels * len(config.multires), config.mlp_width)]
        for _ in range(config.mlp_depth - 1):
            layers += [nn.ReLU(), nn.Linear(config.mlp_width, config.mlp_width)]
        head = nn.Linear(config.mlp_width, num_channels(config.deform_color))
        nn.init.zeros_(head.weight)
        nn.init.zeros_(head.bias)
        layers += [nn.ReLU(), head]
        self.mlp = nn.Sequential(*layers)

    def normalise(self, means: Tensor) -> Tensor:
        """[N, 3] scene units -> [N, 3] in [-1, 1] over the bounds (outside values unclamped)."""
        span = (self.bounds_hi - self.bounds_lo).clamp_min(1e-6)
        return (means - self.bounds_lo) / span * 2.0 - 1.0

    def features(self, means: Tensor, t: float) -> Tensor:
        """[N, 3] canonical means at time t -> [C x scales, N] plane features."""
        time = 2.0 * min(max(float(t), 0.0), 1.0) - 1.0
        return plane_features(self.normalise(means), time, list(self.spatial_planes),
                              list(self.time_planes))

    def forward(self, means: Tensor, attributes: dict[str, Tensor], t: float) -> Deformation:
        channels = self.mlp(self.features(means, t).T)  # [N, 10 or 13]
        return Deformation.from_channels(channels, self.position_scale())

    def regularisation(self) -> dict[str, Tensor]:
        """plane_tv: per spatial plane, the mean squared difference of neighbouring cells along
        each of its two axes, summed over axes, planes and scales (K-Planes' plane TV).
        time_smoothness: per spatio-temporal plane, the mean squared second difference along
        time, summed over planes and scales (K-Planes/4DGS time smoothness)."""
        plane_tv = sum(_mean_square_per_plane(torch.diff(plane, dim=2))
                       + _mean_square_per_plane(torch.diff(plane, dim=3))
                       for plane in self.spatial_planes)
        time_smoothness = sum(_mean_square_per_plane(torch.diff(plane, n=2, dim=2))
                              for plane in self.time_planes)
        return {"plane_tv": plane_tv, "time_smoothness": time_smoothness}

    def regularisation_names(self) -> tuple[str, ...]:
        return ("plane_tv", "time_smoothness")

    def volume_samples(self) -> int:
        return self.config.volume_samples

    def volume_step(self) -> float:
        """volume_step_cells cells of the finest spatial plane along the widest axis."""
        finest = max(plane.shape[-1] for plane in self.spatial_planes)
        span = float((self.bounds_hi - self.bounds_lo).max())
        return self.config.volume_step_cells * span / max(finest - 1, 1)

    def per_gaussian_attributes(self, num: int) -> dict[str, Tensor]:
        return {}

    def param_groups(self) -> list[ParamGroup]:
        config = self.config
        return [ParamGroup("hexplane_grid", list(self.spatial_planes), config.grid_lr,
                           config.grid_lr * config.lr_decay),
                ParamGroup("hexplane_time_grid", list(self.time_planes), config.time_grid_lr,
                           config.time_grid_lr * config.lr_decay),
                ParamGroup("hexplane_mlp", list(self.mlp.parameters()), config.mlp_lr,
                           config.mlp_lr * config.lr_decay)]


def plane_features(coords: Tensor, time: float, spatial_planes: list[Tensor],
                   time_planes: list[Tensor], backend: Backend = "auto") -> Tensor:
    """Normalised coordinates [N, 3] (x, y, z in [-1, 1], outside values border-clamped) at the
    normalised time `time` in [-1, 1], with per scale the spatial [3, C, R, R] and temporal
    [3, C, T, R] planes -> [C x scales, N] features (see HexPlaneField).

    backend "native": the fused kernel (float32 CPU tensors); "reference": grid_sample; "auto":
    native when the inputs are float32 on the CPU and the kernel is built, else the reference.
    """
    if resolve_backend("hexplane", backend, [coords, *spatial_planes, *time_planes]) == "native":
        stacks = [plane for pair in zip(spatial_planes, time_planes) for plane in pair]
        return _NativePlaneFeatures.apply(coords, time, *stacks).T
    spatial_grid = torch.stack([coords[:, [a for a, _ in SPATIAL_AXES]],
                                coords[:, [b for _, b in SPATIAL_AXES]]], dim=-1)  # [N, 3, 2]
    time_grid = torch.stack([coords, torch.full_like(coords, time)], -1)  # [N, 3, 2]: (x|y|z, t)
    scales = []
    for spatial, temporal in zip(spatial_planes, time_planes):
        xy, xz, yz = _sample(spatial, spatial_grid).unbind(0)  # [C, N] each
        xt, yt, zt = _sample(temporal, time_grid).unbind(0)  # [C, N] each
        scales.append(xy * xz * yz * (xt * yt * zt))
    return torch.cat(scales, dim=0)  # [C x scales, N]


def _native_planes(stacks: list[Tensor]) -> list:
    """Per scale [3, C, R, R] spatial and [3, C, T, R] temporal stacks -> the flat list of
    [C, H, W] arrays the kernel takes: xy, xz, yz, xt, yt, zt of each scale in turn."""
    return [plane.numpy() for stack in stacks for plane in stack.unbind(0)]


class _NativePlaneFeatures(torch.autograd.Function):
    """Autograd wrapper of the native sampler: coordinates [N, 3], the time (a float, no
    gradient) and the spatial and temporal plane stacks of each scale in turn -> [N, C x scales]."""

    @staticmethod
    def forward(ctx, coords: Tensor, time: float, *stacks: Tensor) -> Tensor:
        points = torch.cat([coords.detach(), coords.new_full((coords.shape[0], 1), time)], dim=1)
        stacks = tuple(stack.detach().contiguous() for stack in stacks)
        out = coords.new_empty(coords.shape[0], len(stacks) // 2 * stacks[0].shape[1])
        native_module().hexplane_forward(points.numpy(), _native_planes(stacks), out.numpy())
        ctx.save_for_backward(points, *stacks)
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor | None, ...]:
        points, *stacks = ctx.saved_tensors
        grad_coords = points.new_empty(points.shape[0], 3)
        grad_stacks = [torch.empty_like(stack) for stack in stacks]
        native_module().hexplane_backward(
            points.numpy(), _native_planes(stacks), grad_out.contiguous().numpy(),
            grad_coords.numpy(), _native_planes(grad_stacks))
        return grad_coords, None, *grad_stacks


def _sample(planes: Tensor, points: Tensor) -> Tensor:
    """Bilinear lookup of planes [P, C, H, W] at points [N, P, 2] ((width, height) coordinates in
    [-1, 1], border-clamped) -> [P, C, N]. The points form a [P, 1, N] grid: a row, along which
    PyTorch's CPU kernel vectorises."""
    grid = points.transpose(0, 1).unsqueeze(1).contiguous()  # [P, 1, N, 2]
    return F.grid_sample(planes, grid, mode="bilinear", padding_mode="border",
                         align_corners=True)[:, :, 0]


def _mean_square_per_plane(differences: Tensor) -> Tensor:
    """[P, ...] -> scalar: the mean square of each plane's entries, summed over the P planes;
    0 for planes without entries (a time axis of 2 cells, one frame's, has no second
    difference)."""
    squares = differences.square().flatten(1)
    return (squares.sum(dim=1) / max(squares.shape[1], 1)).sum()

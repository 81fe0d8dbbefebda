"""The deformation-field component: offsets of the canonical Gaussians at a time t in [0, 1].

A field maps the canonical means [N, 3], the per-Gaussian attributes it keeps in
`GaussianModel.params` (so that densification clones, splits and prunes them with the Gaussians)
and a time t to a `Deformation`. Fields first produce one [N, D] tensor of channels, in the order
means (3), log-scales (3), quaternion (4) and, when colour deforms, SH DC colour (3);
`Deformation.from_channels` splits it.

Mean offsets are produced in units of `position_scale()`, half the diagonal of the canonical point
cloud's bounding box (`set_bounds`), and scaled to scene units on output. One learning rate thus
suits scenes in millimetres or metres, as 3DGS achieves by multiplying position learning rates
by the scene extent.

As a component (`surgsplat.model.component`), a field sets its bounds from the initial points,
owns its per-Gaussian attributes and network parameters, moves the Gaussians in `transform`, and
offers its regularisers as loss terms (weighted by the method's `losses` config); its volume term
covers the tissue Gaussians, as the method's components declare them (`model.membership`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass

import torch
from torch import Tensor

from surgsplat.model.component import Component, FrameTime, SetupContext
from surgsplat.model.gaussians import GaussianModel
from surgsplat.model.membership import tissue_members
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState

GEOMETRY_CHANNELS = 10
"""Deformed geometry channels: mean offset (3), log-scale offset (3), quaternion offset (4)."""
COLOR_CHANNELS = 3
"""Deformed colour channels: SH DC offset (3)."""


def time_capacity(num_frames: int, short_clip: int, frames_per_unit: int, maximum: int) -> int:
    """Units of temporal capacity (time cells, basis functions) for a clip of `num_frames`.

    Short clips get one unit per two frames, at most `short_clip`, so held-out times are
    interpolated, not memorised. Longer clips, whose motion has more events to follow, get one
    unit per `frames_per_unit` frames once that exceeds `short_clip`, up to `maximum`. At least
    2. Idempotent: feeding the result back as `short_clip` gives it again.
    """
    return max(2, min(short_clip, num_frames // 2),
               min(maximum, num_frames // max(frames_per_unit, 1)))


def num_channels(deform_color: bool) -> int:
    """Channels a field produces per Gaussian: 10 for geometry, 13 with colour."""
    return GEOMETRY_CHANNELS + (COLOR_CHANNELS if deform_color else 0)


@dataclass
class Deformation:
    """Offsets of every Gaussian at one time; all zero is the canonical state."""

    d_means: Tensor  # [N, 3] offset of the mean (scene units)
    d_log_scales: Tensor  # [N, 3] added to the log-scales
    d_quats: Tensor  # [N, 4] added to the (unnormalised) quaternion (w, x, y, z)
    d_colors: Tensor | None  # [N, 3] added to the SH DC colour coefficients, or None

    @classmethod
    def from_channels(cls, channels: Tensor, position_scale: Tensor) -> "Deformation":
        """Split channels [N, 10] or [N, 13] (see num_channels); mean offsets are multiplied by
        position_scale (a scalar tensor) to give scene units."""
        known = (num_channels(False), num_channels(True))
        if channels.dim() != 2 or channels.shape[1] not in known:
            raise ValueError(f"expected [N, 10] or [N, 13] deformation channels, got "
                             f"{tuple(channels.shape)}")
        has_color = channels.shape[1] > GEOMETRY_CHANNELS
        d_colors = channels[:, GEOMETRY_CHANNELS:] if has_color else None
        # The log-scales are copied out of the strided slice: their consumer is an exp, which
        # PyTorch vectorises only on contiguous memory (on the slice it is 18x slower, 2.4 ms at
        # 58k Gaussians, against 0.25 ms for the copy and the exp).
        return cls(d_means=channels[:, 0:3] * position_scale,
                   d_log_scales=channels[:, 3:6].contiguous(),
                   d_quats=channels[:, 6:10], d_colors=d_colors)


class DeformationField(Component, ABC):
    """A deformation over time of N canonical Gaussians.

    Holds the canonical point cloud's bounding box as buffers (bounds_lo, bounds_hi [3], scene
    units), so that it travels with the field's state_dict into checkpoints.
    """
    phase = Phase.DEFORMATION

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("bounds_lo", torch.full((3,), -1.0))
        self.register_buffer("bounds_hi", torch.full((3,), 1.0))
        self._method: tuple[Component, ...] = ()  # the method's components (plain references)

    def set_bounds(self, lo: Tensor, hi: Tensor) -> None:
        """Set the canonical point cloud's axis-aligned bounding box, lo [3] and hi [3]."""
        if lo.shape != (3,) or hi.shape != (3,):
            raise ValueError(f"bounds must be two [3] tensors, got {tuple(lo.shape)} and "
                             f"{tuple(hi.shape)}")
        if not (torch.isfinite(lo).all() and torch.isfinite(hi).all() and (hi >= lo).all()):
            raise ValueError(f"bounds must be finite with hi >= lo, got lo={lo.tolist()} "
                             f"hi={hi.tolist()}")
        self.bounds_lo.copy_(lo.detach())
        self.bounds_hi.copy_(hi.detach())

    def position_scale(self) -> Tensor:
        """Scalar: half the diagonal of the bounds, the unit of mean offsets before scaling."""
        return 0.5 * (self.bounds_hi - self.bounds_lo).norm().clamp_min(1e-6)

    # ---- the component contract ----
    def bind(self, components: Mapping[str, Component]) -> None:
        self._method = tuple(components.values())

    def setup(self, context: SetupContext) -> None:
        self.set_bounds(context.points.min(dim=0).values, context.points.max(dim=0).values)

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        return self.per_gaussian_attributes(context.points.shape[0])

    def transform(self, state: GaussianState, gaussians: GaussianModel,
                  when: FrameTime) -> GaussianState:
        """Offsets evaluated at the centres of `state` (the canonical means, or where a
        component before this one put them, e.g. anchored on a mesh) with the field's
        attributes, added to `state`."""
        delta = self(state.means, dict(gaussians.params), when.time)
        if delta.d_colors is not None:
            state = state.with_dc_offset(delta.d_colors)
        return state.replace(means=state.means + delta.d_means,
                             scales=state.scales * torch.exp(delta.d_log_scales),
                             quats=state.quats + delta.d_quats)

    def loss_names(self) -> tuple[str, ...]:
        return self.regularisation_names() + (("volume",) if self.volume_samples() > 0 else ())

    def losses(self, context, active: frozenset[str]) -> dict[str, Tensor]:
        terms = {name: value for name, value in self.regularisation().items() if name in active}
        if "volume" in active:
            terms["volume"] = self.volume_loss(context.gaussians, context.when.time)
        return terms

    def volume_loss(self, gaussians: GaussianModel, t: float) -> Tensor:
        """Volume preservation: the sum (not the mean) over tissue Gaussians (every Gaussian
        when no component of the method models a tool) of (det J - 1)^2, estimated without bias
        by the mean over `volume_samples()` random ones times their count; J = I + d(mean
        offset)/dx the deformation's spatial Jacobian at the canonical mean, by central
        differences of step `volume_step()` (scene units)."""
        params = gaussians.params
        tissue = tissue_members(self._method, gaussians)
        candidates = (torch.arange(gaussians.num_gaussians) if tissue is None
                      else tissue.nonzero()[:, 0])
        if candidates.numel() == 0:
            return params["means"].sum() * 0.0
        chosen = candidates[torch.randperm(candidates.numel())[:self.volume_samples()]]
        energy = (self.jacobian_determinants(params, chosen, t) - 1.0).square()
        return energy.mean() * candidates.numel()

    def jacobian_determinants(self, params, rows: Tensor, t: float) -> Tensor:
        """[S] det(I + d(mean offset)/dx) of the Gaussians `rows` [S] at time t, by central
        differences of step `volume_step()` along each canonical axis."""
        means = params["means"][rows].detach()  # [S, 3]
        attributes = {name: value[rows] for name, value in params.items()}
        step = self.volume_step()
        shifts = torch.eye(3, dtype=means.dtype) * step  # [3, 3]
        probes = torch.cat([means[:, None] + shifts, means[:, None] - shifts], 1)  # [S, 6, 3]
        repeated = {name: value.repeat_interleave(6, dim=0) for name, value in attributes.items()}
        offsets = self(probes.reshape(-1, 3), repeated, t).d_means.reshape(-1, 6, 3)
        columns = (offsets[:, :3] - offsets[:, 3:]) / (2.0 * step)  # [S, axis k, d offset / dx_k]
        jacobian = torch.eye(3, dtype=means.dtype) + columns.transpose(1, 2)  # [S, 3, 3]
        return torch.linalg.det(jacobian)

    def volume_samples(self) -> int:
        """Gaussians per step of the "volume" loss; 0 = the field offers no such loss."""
        return 0

    def volume_step(self) -> float:
        """Central-difference step of the volume loss, scene units."""
        return 1e-3 * float(self.position_scale())

    def regularisation_names(self) -> tuple[str, ...]:
        """Names of the regularisers `regularisation()` returns."""
        return ()

    # ---- what each field defines ----
    @abstractmethod
    def per_gaussian_attributes(self, num: int) -> dict[str, Tensor]:
        """Initial learnable per-Gaussian tensors, name -> [num, ...], stored with the Gaussians."""

    @abstractmethod
    def forward(self, means: Tensor, attributes: dict[str, Tensor], t: float) -> Deformation:
        """Offsets at time t of Gaussians with canonical means [N, 3] and their attributes."""

    def regularisation(self) -> dict[str, Tensor]:
        """Named scalar regularisers (loss terms, weighted by the method's `losses` config)."""
        return {}

"""Gaussian-basis deformation: every Gaussian moves along its own curve over time.

Every Gaussian carries its own deformation over time, a linear combination of B Gaussian basis
functions:

    psi(t) = sum_j w_j b(t; theta_j, sigma_j),  b(t; theta, sigma) = exp(-(t-theta)^2 / (2 sigma^2))

with a learnable amplitude vector w_j (one entry per deformed channel: mean 3, log-scale 3,
quaternion 4, and SH DC colour 3 when colour deforms) and a learnable centre theta_j and width
sigma_j per basis function and Gaussian. The deformation is thus one vector-valued curve per
Gaussian whose channels share the basis functions. Giving each channel its own centres and widths
would make the basis [N, D, B] instead of [N, B]; sharing them makes the field several times
cheaper on a CPU.

Per-Gaussian attributes (in GaussianModel.params, so densification carries them along):
basis_weights [N, D, B] (mean channels in units of the bounds' half-diagonal, see
deformation.py), basis_centres [N, B] (time) and basis_log_widths [N, B] (log sigma, keeping sigma
positive). Initially the weights are 0 (identity), the centres evenly spread over [0, 1] and every
width `init_width` times the spacing of the centres, so that neighbouring bases overlap.
The field has no network parameters and no regulariser.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from surgsplat.errors import SurgsplatError
from surgsplat.fields.deformation import (Deformation, DeformationField, num_channels,
                                          time_capacity)
from surgsplat.model.capabilities import Retimable
from surgsplat.model.component import ComponentConfig, SceneInfo
from surgsplat.model.gaussians import GaussianModel
from surgsplat.render.native import Backend, dense_grad, native_module, resolve_backend

WEIGHTS = "basis_weights"
CENTRES = "basis_centres"
LOG_WIDTHS = "basis_log_widths"


@dataclass
class BasisCurvesConfig(ComponentConfig):
    """Basis size, initial width and learning rates of per-Gaussian curves over time: the
    Gaussian-basis field's (which move the Gaussians) and the colour curves'
    (`model.color_curves`). Their defaults are measured on the field."""

    num_basis: int = field(default=8, metadata={"range": "[2, inf)"})
    """Number B of Gaussian basis functions per Gaussian (at least 2). Eight fit the smooth
    tissue motion of a clip of a few seconds; more let each Gaussian's curve chase noise
    (measurements: docs/methods/shared-components.md)."""
    long_clip_frames_per_basis: int = field(default=250, metadata={"range": "[1, inf)"})
    """Clips longer than this x num_basis frames get one basis function per this many frames.
    Every basis function costs each Gaussian D + 2 parameters, hence the sparse growth."""
    max_basis: int = field(default=16, metadata={"range": "[2, inf)", "at_least": "num_basis"})
    """Upper limit of the basis functions of a long clip, at least num_basis (per-Gaussian
    memory and time grow linearly with it)."""
    init_width: float = field(default=1.0, metadata={"range": "(0, inf)"})
    """Initial width sigma of every basis function, in units of the spacing of the centres."""
    weights_lr: float = field(default=2.5e-4, metadata={"range": "[0, inf)"})
    """Adam learning rate of the basis amplitudes. Low: with a few thousand CPU iterations each
    Gaussian sees every frame only a few dozen times, and a larger rate (such as 1.6e-3) leaves
    the independent per-Gaussian curves jittering (measurements:
    docs/methods/shared-components.md)."""
    centres_lr: float = field(default=1.6e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the basis centres (time units; the clip spans [0, 1])."""
    log_widths_lr: float = field(default=1e-2, metadata={"range": "[0, inf)"})
    """Adam learning rate of the basis log-widths."""
    lr_decay: float = field(default=0.1, metadata={"range": "(0, 1]"})
    """Final over initial learning rate of the amplitudes, centres and widths (exponential
    decay over the run, as the means decay). At a constant rate they keep moving the Gaussians
    while the means' own rate falls 100x, so the curves still jitter with each step's frame at
    the end of training (measurements: docs/methods/shared-components.md)."""

    def resolve(self, scene: SceneInfo) -> "BasisCurvesConfig":
        """This config for the scene's clip: at most one basis function per two frames, so that
        the curves cannot interpolate the held-out times arbitrarily; more for a long clip
        (`time_capacity`)."""
        return dataclasses.replace(self, num_basis=time_capacity(
            scene.num_frames, self.num_basis, self.long_clip_frames_per_basis, self.max_basis))

    def curve_lrs(self, weights: str, centres: str, log_widths: str
                  ) -> dict[str, tuple[float, float]]:
        """Adam learning rates of the curves' three attributes, by the names they are kept
        under in `GaussianModel.params`: (initial, final), the final `lr_decay` of the
        initial."""
        return {name: (rate, rate * self.lr_decay)
                for name, rate in ((weights, self.weights_lr), (centres, self.centres_lr),
                                   (log_widths, self.log_widths_lr))}


@dataclass
class GaussianBasisConfig(BasisCurvesConfig, kind="gaussian_basis"):
    """A Gaussian-basis deformation field: its curves, and whether colour deforms too."""

    deform_color: bool = False
    """Also deform the SH DC colour."""

    def build(self) -> "GaussianBasisField":
        return GaussianBasisField(self)


class GaussianBasisField(DeformationField):
    """Per-Gaussian sums of Gaussian basis functions over time; see the module docstring."""
    provides = (Retimable,)

    def __init__(self, config: GaussianBasisConfig):
        super().__init__()
        if config.num_basis < 2:
            raise SurgsplatError(f"gaussian_basis num_basis must be >= 2, got {config.num_basis}")
        if config.init_width <= 0:
            raise SurgsplatError(f"gaussian_basis init_width must be > 0, got {config.init_width}")
        self.config = config
        self.num_channels = num_channels(config.deform_color)

    def per_gaussian_attributes(self, num: int) -> dict[str, Tensor]:
        weights, centres, log_widths = identity_curves(num, self.num_channels,
                                                       self.config.num_basis,
                                                       self.config.init_width)
        return {WEIGHTS: weights, CENTRES: centres, LOG_WIDTHS: log_widths}

    def forward(self, means: Tensor, attributes: dict[str, Tensor], t: float) -> Deformation:
        weights = attributes[WEIGHTS]  # [N, D, B]
        if weights.shape[1:] != (self.num_channels, self.config.num_basis):
            raise ValueError(f"{WEIGHTS} must be [N, {self.num_channels}, "
                             f"{self.config.num_basis}], got {tuple(weights.shape)}")
        channels = deformation_channels(weights, attributes[CENTRES], attributes[LOG_WIDTHS], t)
        return Deformation.from_channels(channels, self.position_scale())

    def attribute_lrs(self) -> dict[str, tuple[float, float]]:
        return self.config.curve_lrs(WEIGHTS, CENTRES, LOG_WIDTHS)

    def retime(self, gaussians: GaussianModel, factor: float) -> None:
        retime_curves(gaussians, CENTRES, LOG_WIDTHS, factor)


@torch.no_grad()
def retime_curves(gaussians: GaussianModel, centres: str, log_widths: str,
                  factor: float) -> None:
    """Compress every Gaussian's curve (its basis centres and log-widths, by the names they are
    kept under in `gaussians.params`) into [0, factor] of time: exact, the curve at time
    factor x t is the one that was at t."""
    gaussians.params[centres].mul_(factor)
    gaussians.params[log_widths].add_(math.log(factor))


def identity_curves(num: int, channels: int, num_basis: int,
                    init_width: float) -> tuple[Tensor, Tensor, Tensor]:
    """Initial curves of `num` Gaussians, all zero: weights [num, channels, num_basis], centres
    [num, num_basis] evenly spread over [0, 1] and log-widths [num, num_basis] of `init_width`
    times the centres' spacing, so that neighbouring basis functions overlap."""
    spacing = 1.0 / (num_basis - 1)
    return (torch.zeros(num, channels, num_basis),
            torch.linspace(0.0, 1.0, num_basis).repeat(num, 1),
            torch.full((num, num_basis), math.log(init_width * spacing)))


def deformation_channels(weights: Tensor, centres: Tensor, log_widths: Tensor, t: float,
                         backend: Backend = "auto") -> Tensor:
    """[N, D] channels sum_b weights [N, D, B] b(t; centres [N, B], exp(log_widths [N, B])).

    backend "native": the fused kernel (csrc/basis: the basis, the weighted sum and their
    gradients in one pass over the Gaussians, float32 CPU tensors); "reference": PyTorch
    (`deformation_channels_reference`); "auto": native when it can run the inputs.
    """
    tensors = [weights, centres, log_widths]
    if resolve_backend("gaussian_basis", backend, tensors) == "native":
        return _NativeGaussianBasis.apply(weights, centres, log_widths, float(t))
    return deformation_channels_reference(weights, centres, log_widths, t)


def deformation_channels_reference(weights: Tensor, centres: Tensor, log_widths: Tensor,
                                   t: float) -> Tensor:
    """PyTorch reference of `deformation_channels` (any dtype, autograd's gradients)."""
    basis = basis_values(centres, log_widths, t)  # [N, B]
    return torch.einsum("ndb,nb->nd", weights, basis)


def basis_values(centres: Tensor, log_widths: Tensor, t: float) -> Tensor:
    """[N, B] basis b(t; theta, sigma) = exp(-(t - theta)^2 / (2 sigma^2)) at time t, from the
    centres theta [N, B] and sigma = exp(log_widths [N, B])."""
    z = (t - centres) * torch.exp(-log_widths)
    return torch.exp(-0.5 * z * z)


class _NativeGaussianBasis(torch.autograd.Function):
    """Autograd wrapper of the native kernels; the time is a constant."""

    @staticmethod
    def forward(ctx, weights: Tensor, centres: Tensor, log_widths: Tensor, t: float) -> Tensor:
        inputs = [x.detach().contiguous() for x in (weights, centres, log_widths)]
        out = weights.new_empty(weights.shape[:2])
        native_module().gaussian_basis_forward(*(x.numpy() for x in inputs), t, out.numpy())
        ctx.save_for_backward(*inputs)
        ctx.t = t
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor, Tensor, Tensor, None]:
        weights, centres, log_widths = ctx.saved_tensors
        grads = [torch.empty_like(weights), torch.empty_like(centres),
                 torch.empty_like(log_widths)]
        native_module().gaussian_basis_backward(
            weights.numpy(), centres.numpy(), log_widths.numpy(), ctx.t,
            dense_grad(grad_out, tuple(weights.shape[:2])).numpy(), *(g.numpy() for g in grads))
        return (*grads, None)

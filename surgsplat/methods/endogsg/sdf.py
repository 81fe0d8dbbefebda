"""A neural signed distance field coupled to the Gaussians (Endo-GSG, Sections 3.3-3.4).

The field f(x) lives in canonical space: it is evaluated at the canonical Gaussian centres, and
the deformation component carries the Gaussians (and with them the surface f = 0) to every
time. One canonical surface suits a deforming scene because the deformation, not the SDF, explains
the motion; an SDF evaluated at the deformed centres (the paper's wording) would have to be one
surface for all the frames' shapes at once, and a time-conditioned f(x, t) would need the
deformation's work again and make opacity depend on time.

Encoding: a few dense 3D feature grids of increasing resolution over the canonical bounding box
(a dense multi-resolution grid rather than a hash table: the tissue's box is small, and dense
trilinear lookup is a single vectorised `grid_sample` per level on a CPU), concatenated with the
normalised position and decoded by a 2-layer MLP (Softplus activations). The output is scaled by
half the box diagonal, so f is in scene units and its gradient has length 1 when the Eikonal
loss holds. Gradients of f are taken by tetrahedral finite differences (as Neuralangelo does),
which needs no double backward through the grid lookup.

The coupling, as the component contract expresses it:
- opacity: every tissue Gaussian's opacity (all of them, unless a component of the method marks
  some as tool, `model.membership`) is multiplied by the bell Phi_beta(f(mu)) = 4 s (1 - s),
  s = sigmoid(beta f(mu)) (Eq. 4; beta learnable), also given to densification as
  `opacity_factor`, so pruning, cloning and resets act on the rendered opacity;
- losses on a random subset of tissue Gaussians per step: "eikonal" (Eq. 13), "projection"
  (Eq. 7-8: the centres pulled toward their detached projections on the zero level; the L1
  length over `unit()`, so that its weight does not depend on the scene's unit),
  "orientation" (Eq. 9-10: the shortest axis along the SDF normal) and "sda" (Eq. 6: the
  normalised SDF vector against the normalised signed depth differences of the deformed centres
  to the frame's measured depth). The depth loss of Eq. 5 is the method's depth component, whose
  rendered depth the SDF opacity shapes.

Where the field meets the Gaussians: at their canonical parameters params["means"], also when
another component places the rendered canonical Gaussians elsewhere (DRAWER's mesh anchors clip
them onto the faces of this field's zero level, where f is 0 by construction: the projection loss
would then never pull a drifting mean back, nor would the field learn where the tissue is, and
the mesh is lost over much of the scene; measured: docs/methods/endogsg.md, Deviations).

Sign convention: f > 0 in front of the surface (the camera side, free space), f < 0 behind it.
The field provides the method's `SignedDistanceField` (`model.capabilities`), from which mesh
anchors and the mesh export extract the surface, and the `OpacityFactor` that densification
acts on. `setup` fits the field to the initial point cloud along the first camera's rays before
training.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from surgsplat.errors import SurgsplatError
from surgsplat.image.pinhole import inside_image, project_points
from surgsplat.model.capabilities import OpacityFactor, SignedDistanceField
from surgsplat.model.component import (Component, ComponentConfig, FrameTime, ParamGroup,
                                       RenderContext, SetupContext)
from surgsplat.model.gaussians import GaussianModel
from surgsplat.model.membership import tissue_members
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState
from surgsplat.render.rotation import quaternion_to_matrix

TETRAHEDRON = torch.tensor([[1.0, -1.0, -1.0], [-1.0, -1.0, 1.0], [-1.0, 1.0, -1.0],
                            [1.0, 1.0, 1.0]])
"""Vertices of the regular tetrahedron used for finite-difference gradients."""


@dataclass
class SDFConfig(ComponentConfig, kind="sdf"):
    """Size, schedule and coupling of the signed distance field."""

    resolutions: tuple[int, ...] = field(default=(16, 32, 64), metadata={"range": "[2, 512]"})
    """Cells per axis of each dense feature grid over the canonical box."""
    feature_dim: int = field(default=2, metadata={"range": "[1, inf)"})
    """Feature channels of every grid."""
    mlp_width: int = field(default=32, metadata={"range": "[1, inf)"})
    """Width of the MLP's two hidden layers."""
    grid_lr: float = field(default=1e-3, metadata={"range": "(0, inf)"})
    """Adam learning rate of the feature grids. Adam moves every parameter by about its
    learning rate per step, and f is the MLP's output times `unit()` (half the box diagonal),
    so the zero level moves by a good fraction of that per step: at ten times these rates the
    mean of f at the Gaussians swings by more than the bell's width within tens of steps,
    and meshes extracted from it early (DRAWER's anchors) lie off the tissue (measured:
    docs/methods/endogsg.md, Deviations)."""
    mlp_lr: float = field(default=1e-4, metadata={"range": "(0, inf)"})
    """Adam learning rate of the MLP (see `grid_lr`); the fit to the initial points uses 5x it."""
    lr_decay: float = field(default=0.01, metadata={"range": "(0, 1]"})
    """Final over initial learning rate of the grids and the MLP (exponential decay over the run,
    as the Gaussians' means decay), so that the zero level settles with the centres."""
    beta_lr: float = field(default=1e-2, metadata={"range": "[0, inf)"})
    """Adam learning rate of log(beta); 0 keeps beta fixed at its initial value."""
    bell_width: float = field(default=0.02, metadata={"range": "(0, inf)"})
    """Initial 1 / beta as a fraction of the scene extent (a Gaussian this far from the surface
    keeps 4 s (1 - s) = 0.79 of its opacity)."""
    samples_per_step: int = field(default=2048, metadata={"range": "[1, inf)"})
    """Gaussians drawn per step for the Eikonal, projection, orientation and SDA losses."""
    box_margin: float = field(default=0.15, metadata={"range": "[0, inf)"})
    """Margin added on every side of the initial points' bounding box, as a fraction of its size
    (at least `fit_band` of the extent)."""
    gradient_step: float = field(default=0.5, metadata={"range": "(0, inf)"})
    """Finite-difference step, in cells of the finest grid."""
    fit_steps: int = field(default=200, metadata={"range": "[0, inf)"})
    """Adam steps fitting the field to the initial points along the first camera's rays."""
    fit_band: float = field(default=0.05, metadata={"range": "(0, inf)"})
    """Half-width of the band around the initial points the fit samples, fraction of the extent."""

    def build(self) -> "SDFField":
        return SDFField(self)


class SDFField(Component):
    """grids[l]: [1, C, R_l, R_l, R_l]; box: [2, 3] (lo, hi) canonical bounds, scene units."""
    phase = Phase.OPACITY
    provides = (SignedDistanceField, OpacityFactor)

    def __init__(self, config: SDFConfig):
        super().__init__()
        if not config.resolutions or min(config.resolutions) < 2:
            raise SurgsplatError("sdf needs at least one grid resolution, each >= 2")
        if not 0 < config.lr_decay <= 1:
            raise SurgsplatError(f"sdf lr_decay must be in (0, 1], got {config.lr_decay}")
        self.config = config
        self.grids = nn.ParameterList(
            nn.Parameter(torch.randn(1, config.feature_dim, r, r, r) * 1e-2)
            for r in config.resolutions)
        width = config.mlp_width
        self.mlp = nn.Sequential(
            nn.Linear(config.feature_dim * len(config.resolutions) + 3, width),
            nn.Softplus(beta=20.0), nn.Linear(width, width), nn.Softplus(beta=20.0),
            nn.Linear(width, 1))
        self.log_beta = nn.Parameter(torch.zeros(()))
        self.register_buffer("box", torch.tensor([[-1.0] * 3, [1.0] * 3]))
        self.register_buffer("initial_beta", torch.ones(()))  # 1 / scene units, set by setup
        self._method: tuple[Component, ...] = ()  # the method's components (plain references)

    # ---- the field ----
    def unit(self) -> Tensor:
        """Scalar: half the box diagonal, the scene length of one unit of MLP output."""
        return 0.5 * (self.box[1] - self.box[0]).norm()

    def normalise(self, points: Tensor) -> Tensor:
        """[P, 3] scene units -> [P, 3] in [-1, 1] over the box (outside values unclamped)."""
        return (points - self.box[0]) / (self.box[1] - self.box[0]) * 2.0 - 1.0

    def signed_distance(self, points: Tensor) -> Tensor:
        """f at world points [P, 3] (canonical space, scene units) -> [P] in scene units."""
        coords = self.normalise(points)
        grid = coords.flip(-1).view(1, 1, 1, -1, 3)  # grid_sample wants (x, y, z) -> (W, H, D)
        features = [F.grid_sample(level, grid, mode="bilinear", padding_mode="border",
                                  align_corners=True).view(level.shape[1], -1).T
                    for level in self.grids]
        return self.mlp(torch.cat([*features, coords], dim=1))[:, 0] * self.unit()

    def gradient_step(self) -> Tensor:
        """Scalar finite-difference step in scene units (a fraction of the finest cell)."""
        cell = (self.box[1] - self.box[0]).min() / (max(self.config.resolutions) - 1)
        return self.config.gradient_step * cell

    def value_and_gradient(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """f [P] and its gradient [P, 3] at points [P, 3] (see `tetrahedral_gradient`)."""
        return tetrahedral_gradient(self.signed_distance, points, self.gradient_step())

    def beta(self) -> Tensor:
        """Scalar sharpness of the bell, 1 / scene units."""
        return self.initial_beta * torch.exp(self.log_beta)

    def bell(self, distance: Tensor) -> Tensor:
        """Phi_beta(f) = 4 e^(-beta f) / (1 + e^(-beta f))^2 in (0, 1], 1 on the surface (Eq. 4)."""
        s = torch.sigmoid(self.beta() * distance)
        return 4.0 * s * (1.0 - s)

    # ---- the component contract ----
    def bind(self, components: Mapping[str, Component]) -> None:
        self._method = tuple(components.values())

    def setup(self, context: SetupContext) -> None:
        points = context.points
        lo, hi = points.min(dim=0).values, points.max(dim=0).values
        # at least the fit's band, so that the samples of `_fit` lie inside the grids
        margin = ((hi - lo) * self.config.box_margin).clamp_min(
            self.config.fit_band * context.scene_extent)
        self.box.copy_(torch.stack([lo - margin, hi + margin]))
        self.initial_beta.fill_(1.0 / (self.config.bell_width * context.scene_extent))
        self._fit(points, context)

    def _fit(self, points: Tensor, context: SetupContext) -> None:
        """Fit f to the initial points: zero on them, the signed distance along the first
        camera's ray around them (positive toward the camera), unit gradient."""
        extent = context.scene_extent
        centre = context.frames[0].camera.camera_to_world[:3, 3]
        toward_camera = nn.functional.normalize(centre - points, dim=1)  # [M, 3]
        band = self.config.fit_band * extent
        parameters = [*self.grids, *self.mlp.parameters()]
        optimizer = torch.optim.Adam(parameters, lr=self.config.mlp_lr * 5)
        generator = torch.Generator().manual_seed(0)
        count = min(self.config.samples_per_step, points.shape[0])
        for _ in range(self.config.fit_steps):
            pick = torch.randint(points.shape[0], (count,), generator=generator)
            offset = (torch.rand(count, generator=generator) * 2 - 1) * band
            samples = points[pick] + offset[:, None] * toward_camera[pick]
            value, gradient = self.value_and_gradient(samples)
            loss = ((value - offset).abs().mean() / band
                    + 0.1 * eikonal_loss(gradient))
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()

    def param_groups(self) -> list[ParamGroup]:
        config = self.config
        groups = [ParamGroup("sdf_grid", list(self.grids), config.grid_lr,
                             config.grid_lr * config.lr_decay),
                  ParamGroup("sdf_mlp", list(self.mlp.parameters()), config.mlp_lr,
                             config.mlp_lr * config.lr_decay)]
        if self.config.beta_lr > 0:
            groups.append(ParamGroup("sdf_beta", [self.log_beta], self.config.beta_lr))
        return groups

    def tissue_bell(self, gaussians: GaussianModel) -> Tensor:
        """[N] the bell of f at the canonical centres; 1 for Gaussians that a component of the
        method models as tool (the field describes the tissue surface)."""
        factor = self.bell(self.signed_distance(gaussians.params["means"]))
        tissue = tissue_members(self._method, gaussians)
        return factor if tissue is None else torch.where(tissue, factor, 1.0)

    def transform(self, state: GaussianState, gaussians: GaussianModel,
                  when: FrameTime) -> GaussianState:
        """Opacities times the bell of f at the canonical centres (Eq. 4)."""
        return state.replace(opacities=state.opacities * self.tissue_bell(gaussians))

    @torch.no_grad()
    def opacity_factor(self, gaussians: GaussianModel) -> Tensor:
        return self.tissue_bell(gaussians)

    def loss_names(self) -> tuple[str, ...]:
        return ("eikonal", "projection", "orientation", "sda")

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        params = context.gaussians.params
        tissue = tissue_members(self._method, context.gaussians)
        rows = (torch.arange(params["means"].shape[0]) if tissue is None
                else tissue.nonzero()[:, 0])
        pick = rows[torch.randperm(rows.numel())[:self.config.samples_per_step]]
        means = params["means"][pick]  # [K, 3] canonical
        value, gradient = self.value_and_gradient(means)
        normal = nn.functional.normalize(gradient, dim=1).detach()  # [K, 3]
        terms: dict[str, Tensor] = {}
        if "eikonal" in active:
            terms["eikonal"] = eikonal_loss(gradient)
        if "projection" in active:
            terms["projection"] = projection_loss(means, value, normal) / self.unit()
        if "orientation" in active:
            terms["orientation"] = orientation_loss(params["quats"][pick],
                                                    params["log_scales"][pick], normal)
        if "sda" in active:
            terms["sda"] = self._sda(context, pick, value)
        return terms

    def _sda(self, context: RenderContext, pick: Tensor, value: Tensor) -> Tensor:
        """Eq. 6 over the picked Gaussians whose deformed centre projects onto a tissue pixel
        with a measured depth."""
        frame, camera = context.frame, context.camera
        if frame.depth is None:
            return value.sum() * 0.0
        pixel, z = project_points(context.state.means[pick].detach(), camera.K,
                                  camera.world_to_camera)
        rows = pixel[:, 1].clamp(0, camera.height - 1)
        columns = pixel[:, 0].clamp(0, camera.width - 1)
        measured = frame.depth[rows, columns]
        seen = (inside_image(pixel, z, camera.width, camera.height) & frame.tissue[rows, columns]
                & (measured > 0))
        return sda_loss(value[seen], measured[seen] - z[seen])


def tetrahedral_gradient(function, points: Tensor, step: Tensor | float
                         ) -> tuple[Tensor, Tensor]:
    """Value [P] and gradient [P, 3] of a scalar field `function` ([P, 3] -> [P]) at points
    [P, 3] from its samples at the four vertices x + h v_k of a regular tetrahedron:
    grad f ~ sum_k v_k f(x + h v_k) / (4 h), f(x) ~ their mean (exact for linear fields; the
    gradient's error is O(h |Hessian|) otherwise, which also smooths the field's finest detail
    below h). Differentiable in the field's parameters and the points."""
    vertices = TETRAHEDRON.to(points.dtype)
    offsets = vertices * step  # [4, 3]
    samples = function((points[:, None] + offsets).reshape(-1, 3)).view(-1, 4)
    return samples.mean(dim=1), samples @ vertices / (4.0 * step)


def eikonal_loss(gradient: Tensor) -> Tensor:
    """Mean (|grad f| - 1)^2 over gradients [K, 3] (Eq. 13)."""
    return (gradient.norm(dim=1) - 1.0).square().mean()


def projection_loss(means: Tensor, value: Tensor, normal: Tensor) -> Tensor:
    """Mean L1 distance between centres [K, 3] and their first-order projections onto the zero
    level set x_proj = x - f(x) n (Eq. 7-8; value [K] = f(x) in scene units, n [K, 3] the unit
    SDF normal; with f > 0 in front, the projection steps against the normal). The projection is
    a fixed target (detached), so the loss pulls the centres onto the surface and leaves the field
    alone: its gradient in the means is sign(f n) / K, and none reaches f or n (the field learns
    its surface from the depth, SDA and Eikonal terms; were f differentiated here, the cheapest
    descent would move the surface onto the centres, floaters included)."""
    target = (means - value[:, None] * normal).detach()
    return (means - target).abs().sum(dim=1).mean()


def orientation_loss(quats: Tensor, log_scales: Tensor, normal: Tensor) -> Tensor:
    """Mean squared angle (radians) between each Gaussian's shortest axis and the SDF normal
    [K, 3], orientation-free (Eq. 9-10). quats [K, 4] (w, x, y, z), log_scales [K, 3]."""
    rotation = quaternion_to_matrix(nn.functional.normalize(quats, dim=1))  # [K, 3, 3]
    shortest = log_scales.argmin(dim=1)
    axis = rotation.gather(2, shortest[:, None, None].expand(-1, 3, 1))[..., 0]  # column [K, 3]
    cosine = (axis * normal).sum(dim=1).abs().clamp(max=1.0 - 1e-6)
    return torch.arccos(cosine).square().mean()


def sda_loss(value: Tensor, depth_difference: Tensor) -> Tensor:
    """Eq. 6: the SDF values [K] and the signed depth differences [K] (measured depth minus the
    centre's depth: > 0 in front of the surface) are each normalised to unit length; the loss is
    the L1 distance of the two unit vectors divided by sqrt(K), in [0, 2]. 0 when K = 0."""
    if value.numel() == 0:
        return value.sum() * 0.0
    predicted = value / value.norm().clamp_min(1e-12)
    target = depth_difference / depth_difference.norm().clamp_min(1e-12)
    return (predicted - target).abs().sum() / math.sqrt(value.numel())

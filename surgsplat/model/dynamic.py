"""Canonical Gaussians plus the components of a method: the Gaussians of any frame as plain
tensors, and their render.

The renderer takes tensors, never this module: `state_at(when)` is the seam between them. The
model knows components only through the contract of `surgsplat.model.component`.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from surgsplat.data.scene import Camera
from surgsplat.errors import SurgsplatError
from surgsplat.model.capabilities import (CameraCorrection, CanonicalPlacement,
                                          DensifyWeighting, GradientWeighting, OpacityFactor)
from surgsplat.model.channels import BASE_CHANNELS, ChannelDescriptor
from surgsplat.model.component import (Capability, Component, Diagnostics, FrameTime, ParamGroup,
                                       RenderContext, provider, providers)
from surgsplat.model.gaussians import GaussianModel
from surgsplat.model.membership import tissue_members, tool_members
from surgsplat.model.phases import order_by_phase
from surgsplat.model.state import GaussianState
from surgsplat.render.render import RenderOutput, render


class SplatModel(nn.Module):
    """Canonical Gaussians and named components, applied in the order of their phases
    (`model.phases`; SurgsplatError when no such order exists)."""

    def __init__(self, gaussians: GaussianModel, components: dict[str, Component]):
        super().__init__()
        self.gaussians = gaussians
        self.components = nn.ModuleDict(order_by_phase(components))
        for component in self.components.values():
            component.bind(self.components)

    # ---- the Gaussians at a moment ----
    def canonical_state(self) -> GaussianState:
        """The canonical Gaussians before any component."""
        params = self.gaussians.params
        return GaussianState(means=params["means"], scales=params["log_scales"].exp(),
                             quats=params["quats"],
                             opacities=torch.sigmoid(params["opacity_logits"]),
                             sh=self.gaussians.sh_coeffs(), sh_degree=self.gaussians.sh_degree)

    def canonical_means(self) -> Tensor:
        """[N, 3] where the canonical Gaussians are before any deformation: as the component
        that places them puts them (`CanonicalPlacement`, e.g. anchors on mesh faces), else
        params["means"]."""
        placement = self.find(CanonicalPlacement)
        placed = None if placement is None else placement.canonical_means(self.gaussians)
        return self.gaussians.params["means"] if placed is None else placed

    def before_render(self, when: FrameTime) -> None:
        """Every component's `before_render` for a render at `when` (`render` calls it)."""
        for component in self.components.values():
            component.before_render(self.gaussians, when)

    def state_at(self, when: FrameTime) -> GaussianState:
        """The Gaussians at `when`: the canonical state through every component's transform
        (pure: asking twice changes nothing)."""
        state = self.canonical_state()
        for component in self.components.values():
            state = component.transform(state, self.gaussians, when)
        return state

    def camera_at(self, camera: Camera, when: FrameTime) -> Camera:
        """The camera a frame at `when` is seen with: `camera` through every component's
        `CameraCorrection`, in phase order (the camera itself when no component changes it)."""
        for correction in self.providers(CameraCorrection):
            camera = correction.camera(camera, when)
        return camera

    def render(self, camera: Camera, when: FrameTime, background: Tensor | None = None,
               absgrad: Tensor | None = None) -> tuple[RenderOutput, GaussianState]:
        """The view of `camera` at `when`, with every component's channels and derived maps,
        and the Gaussians that were rendered (after every component's `before_render`; their
        gradients weighted per pixel by the one component's `GradientWeighting`, if any). `camera` is
        rendered as given: a frame's camera goes through `camera_at` first (`render_frame` and
        the Trainer do so)."""
        self.before_render(when)
        state = self.state_at(when)
        channels: dict[str, Tensor] = {}
        for name, component in self.components.items():
            for key, value in component.render_channels(state, self.gaussians, camera, when).items():
                if key in channels:
                    raise SurgsplatError(f"component {name!r} renders channel {key!r}, which "
                                         "another component already renders")
                channels[key] = value
        weighting = self.find(GradientWeighting)
        weights = None if weighting is None else weighting.gradient_weights(self.gaussians, when)
        output = render(state.means, state.scales, state.quats, state.opacities, state.sh,
                        camera.K, camera.width, camera.height,
                        world_to_camera=camera.world_to_camera, sh_degree=state.sh_degree,
                        extras=channels, background=background, absgrad=absgrad,
                        gradient_weights=weights)
        for component in self.components.values():
            component.finish_render(output, camera, when)
        return output, state

    @property
    def separates_tool(self) -> bool:
        """True when a component can leave the tool out (renders with `when.tissue_only`)."""
        return any(component.separates_tool for component in self.components.values())

    # ---- what other layers ask of the components ----
    def channel_descriptors(self) -> tuple[ChannelDescriptor, ...]:
        """The channels of every render this model makes: the base channels, then those the
        components declare, in order; SurgsplatError when two share a name."""
        channels = list(BASE_CHANNELS)
        for name, component in self.components.items():
            for channel in component.channel_descriptors():
                if channel.name in (known.name for known in channels):
                    raise SurgsplatError(f"component {name!r} declares channel "
                                         f"{channel.name!r}, which the render already has")
                channels.append(channel)
        return tuple(channels)

    def tool_members(self) -> Tensor | None:
        """[N] bool, True = a Gaussian a component models as tool; None without a tool."""
        return tool_members(self.components.values(), self.gaussians)

    def tissue_members(self) -> Tensor | None:
        """[N] bool, True = tissue Gaussian; None when every Gaussian is tissue."""
        return tissue_members(self.components.values(), self.gaussians)

    def find(self, capability: type[Capability]) -> Capability | None:
        """The component that provides `capability` (`model.capabilities`), or None;
        SurgsplatError when several do."""
        return provider(self.components.values(), capability)

    def providers(self, capability: type[Capability]) -> list[Capability]:
        """Every component that provides `capability`, in phase order."""
        return providers(self.components.values(), capability)

    @torch.no_grad()
    def diagnostics(self, when: FrameTime) -> Diagnostics:
        """Every component's measurements of the Gaussians at `when`, merged."""
        state = self.state_at(when)
        merged = Diagnostics()
        for component in self.components.values():
            found = component.frame_diagnostics(state, self.gaussians, when)
            if found is not None:
                merged.summed.update(found.summed)
                merged.averaged.update(found.averaged)
                merged.conventions.update(found.conventions)
        return merged

    # ---- what training needs ----
    def loss_terms(self) -> dict[str, str]:
        """Every loss term name -> the component that computes it."""
        owners: dict[str, str] = {}
        for name, component in self.components.items():
            for term in component.loss_names():
                if term in owners:
                    raise SurgsplatError(f"loss term {term!r} is declared by both components "
                                         f"{owners[term]!r} and {name!r}")
                owners[term] = name
        return owners

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        """The active loss terms of every component, unweighted."""
        terms: dict[str, Tensor] = {}
        for component in self.components.values():
            wanted = active.intersection(component.loss_names())
            if wanted:
                terms.update(component.losses(context, frozenset(wanted)))
        return terms

    @torch.no_grad()
    def opacity_factor(self) -> Tensor | None:
        """[N] product of the components' time-independent opacity factors, or None."""
        return _product(component.opacity_factor(self.gaussians)
                        for component in self.providers(OpacityFactor))

    @torch.no_grad()
    def densify_weights(self, context: RenderContext) -> Tensor | None:
        """[N] product of the components' densification weights for this step, or None."""
        return _product(component.densify_weights(context)
                        for component in self.providers(DensifyWeighting))

    @torch.no_grad()
    def after_step(self, iteration: int) -> None:
        """Every component's work after training step `iteration`."""
        for component in self.components.values():
            component.after_step(self.gaussians, iteration)

    def attribute_lrs(self) -> dict[str, float | tuple[float, float]]:
        """Learning rates of the components' learnt per-Gaussian attributes, by attribute name
        (`Component.attribute_lrs`)."""
        lrs: dict[str, float | tuple[float, float]] = {}
        for component in self.components.values():
            lrs.update(component.attribute_lrs())
        return lrs

    def component_param_groups(self) -> list[ParamGroup]:
        """Optimiser groups of every component's own parameters."""
        return [group for component in self.components.values()
                for group in component.param_groups()]


def _product(factors) -> Tensor | None:
    """The product of the tensors among `factors` that are not None; None if all are."""
    result = None
    for factor in factors:
        if factor is not None:
            result = factor if result is None else result * factor
    return result


@torch.no_grad()
def render_frame(model: SplatModel, camera: Camera, when: FrameTime,
                 background: Tensor | None = None) -> RenderOutput:
    """Render the model at `when` without gradients, e.g. for evaluation and videos, seen with
    `camera` as the components change it (`SplatModel.camera_at`, e.g. a refined pose)."""
    return model.render(model.camera_at(camera, when), when, background)[0]

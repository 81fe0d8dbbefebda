"""Where each component of a method acts: its phase. `SplatModel` applies the components in the
order of their phases, so the order in which a method's config lists them does not matter.

The Gaussians of a frame are the canonical Gaussians through every component's `transform`, in
phase order; the render's derived maps (`finish_render`) follow the same order, which is:
- the anchors place the canonical Gaussians, which the deformation then moves;
- the colour curves change each Gaussian's colour after the deformation and before the tool
  field gates it;
- the tool field moves its Gaussians rigidly over whatever the deformation made of them, and
  gates the gradients of every colour and opacity before the exposure and the SDF scale them;
- the illumination modulates the exposed colour (its colour offset is not scaled by the
  exposure).
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from typing import TYPE_CHECKING

from surgsplat.errors import SurgsplatError

if TYPE_CHECKING:
    from surgsplat.model.component import Component


class Phase(StrEnum):
    """The phases, declared in the order the model applies them. A component class declares
    its phase as a member or its value (`phase = Phase.TOOL`, or `phase = "tool"`)."""

    ANCHOR = "anchor"
    """Places the canonical Gaussians (e.g. anchors on mesh faces)."""
    DEFORMATION = "deformation"
    """Moves the Gaussians to the frame's time (Gaussian-basis, HexPlane)."""
    APPEARANCE = "appearance"
    """Changes each Gaussian's own colour over time (the colour curves)."""
    TOOL = "tool"
    """Moves the tool's Gaussians rigidly, over the deformation (the tool field)."""
    EXPOSURE = "exposure"
    """The frame's colour gain (the exposure curve)."""
    ILLUMINATION = "illumination"
    """Modulates each Gaussian's colour by the frame's illumination state."""
    OPACITY = "opacity"
    """Multiplies every opacity by a factor that does not depend on time (the SDF's bell)."""
    SURFACE = "surface"
    """Changes what the render's surface is: normals, depth (planar Gaussians)."""
    SHADING = "shading"
    """Adds light to the rendered colour from the rendered surface (the specular lobe)."""
    LOSS = "loss"
    """Leaves the Gaussians and the render as they are: loss terms, metrics, capabilities."""
    CAMERA = "camera"
    """Changes the camera a frame is seen with (`CameraCorrection`, per-frame pose refinement),
    not the Gaussians: its place among the phases changes no render."""


ORDER = tuple(Phase)
"""The phases in the order the model applies them."""
SHARED_PHASES = frozenset({Phase.OPACITY, Phase.SHADING, Phase.LOSS})
"""Phases that several components of a method may hold: opacity factors multiply, lobes add,
losses change nothing. Among themselves such components keep the config's order (the order
their terms are computed and summed in). Every other phase takes one component, since two
would act in an undefined order."""


def phase_of(name: str, component: Component) -> Phase:
    """The phase the component `name` declares; SurgsplatError in one line when it declares
    none or an unknown one."""
    try:
        return Phase(component.phase)
    except ValueError:
        raise SurgsplatError(f"component {name!r} ({type(component).__name__}) declares the "
                             f"phase {component.phase!r}; its class's `phase` must be one of "
                             f"{', '.join(ORDER)}") from None


def order_by_phase(components: Mapping[str, Component]) -> dict[str, Component]:
    """`components` (name -> component) in the order of their phases, those of a shared phase
    in the order given; SurgsplatError in one line when a component declares no phase or two
    hold a phase that takes one."""
    phases = {name: phase_of(name, component) for name, component in components.items()}
    holders: dict[Phase, str] = {}
    for name, phase in phases.items():
        if phase in holders and phase not in SHARED_PHASES:
            raise SurgsplatError(f"components {holders[phase]!r} and {name!r} both have the "
                                 f"phase {phase}, which takes one component (their order would "
                                 "be undefined); remove one")
        holders[phase] = name
    return {name: components[name]
            for name in sorted(components, key=lambda name: ORDER.index(phases[name]))}

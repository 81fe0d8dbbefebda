"""Where each component of a method acts: its phase. `SplatModel` applies the components in the
order of their phases, so the order in which a method's config lists them does not matter.

A phase is declared with the phases it comes after (`declare_phase`); the order of the phases
is the one those constraints give, ties kept in the order of declaration. surgsplat's own
phases form one chain (the `Phase` members, declared below); a method package may declare a
phase of its own between two of them (`declare_phase("glaze", after=("shading",),
before=("loss",))`). The Gaussians of a frame are the canonical Gaussians through every
component's `transform`, in phase order; the render's derived maps (`finish_render`) follow the
same order, which is:
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
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

from surgsplat.errors import SurgsplatError

if TYPE_CHECKING:
    from surgsplat.model.component import Component


@dataclass(frozen=True)
class PhaseDeclaration:
    """A phase and its place: the phases it comes after and before, and whether several
    components of a method may hold it."""

    name: str
    after: tuple[str, ...] = ()
    before: tuple[str, ...] = ()
    shared: bool = False
    """True when several components may hold it (opacity factors multiply, lobes add, losses
    change nothing): they keep the config's order among themselves. A phase that is not shared
    takes one component, since two would act in an undefined order."""


PHASES: dict[str, PhaseDeclaration] = {}
"""Every declared phase, by name, in the order of declaration."""


def declare_phase(name: str, after: tuple[str, ...] = (), before: tuple[str, ...] = (),
                  shared: bool = False) -> str:
    """Declare the phase `name`, placed after the phases `after` and before the phases
    `before` (each declared already); returns `name`. SurgsplatError when it is declared
    already, names an unknown phase, or would make the order circular."""
    if name in PHASES:
        raise SurgsplatError(f"phase {name!r} is declared already")
    unknown = [other for other in (*after, *before) if other not in PHASES]
    if unknown:
        raise SurgsplatError(f"phase {name!r} is placed against undeclared phase "
                             f"{unknown[0]!r}; known: {', '.join(PHASES)}")
    PHASES[name] = PhaseDeclaration(name, tuple(after), tuple(before), shared)
    try:
        phase_order()
    except SurgsplatError:
        del PHASES[name]
        raise
    return name


def phase_order() -> tuple[str, ...]:
    """Every declared phase in the order the model applies them: each after the phases it
    comes after, and before those it comes before; ties in the order of declaration."""
    predecessors = {name: set(phase.after) for name, phase in PHASES.items()}
    for phase in PHASES.values():
        for later in phase.before:
            predecessors[later].add(phase.name)
    order: list[str] = []
    while len(order) < len(PHASES):
        ready = next((name for name in PHASES
                      if name not in order and predecessors[name] <= set(order)), None)
        if ready is None:
            raise SurgsplatError("the phases' before/after constraints are circular: "
                                 + ", ".join(name for name in PHASES if name not in order))
        order.append(ready)
    return tuple(order)


class Phase(StrEnum):
    """surgsplat's own phases, in the order the model applies them (each declared after the one
    before it). A component class declares its phase as a member or a declared phase's name
    (`phase = Phase.TOOL`, or `phase = "tool"`)."""

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


SHARED = frozenset({Phase.OPACITY, Phase.SHADING, Phase.LOSS})
"""surgsplat's phases that several components of a method may hold."""
for _previous, _phase in zip((None, *Phase), Phase):
    declare_phase(_phase.value, after=() if _previous is None else (_previous.value,),
                  shared=_phase in SHARED)


def phase_of(name: str, component: Component) -> str:
    """The declared phase the component `name` acts in; SurgsplatError in one line when it
    declares none or an undeclared one."""
    phase = component.phase
    if phase not in PHASES:
        raise SurgsplatError(f"component {name!r} ({type(component).__name__}) declares the "
                             f"phase {phase!r}; its class's `phase` must be a declared phase: "
                             f"{', '.join(phase_order())}")
    return str(phase)


def order_by_phase(components: Mapping[str, Component]) -> dict[str, Component]:
    """`components` (name -> component) in the order of their phases, those of a shared phase
    in the order given; SurgsplatError in one line when a component declares no phase or two
    hold a phase that takes one."""
    phases = {name: phase_of(name, component) for name, component in components.items()}
    holders: dict[str, str] = {}
    for name, phase in phases.items():
        if phase in holders and not PHASES[phase].shared:
            raise SurgsplatError(f"components {holders[phase]!r} and {name!r} both have the "
                                 f"phase {phase}, which takes one component (their order would "
                                 "be undefined); remove one")
        holders[phase] = name
    order = phase_order()
    return {name: components[name]
            for name in sorted(components, key=lambda name: order.index(phases[name]))}

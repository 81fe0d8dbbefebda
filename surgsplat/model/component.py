"""The component contract: every piece of a method (a deformation field, an exposure curve, a loss,
planar Gaussians, ...) is a `Component`, configured by a typed `ComponentConfig`.

The Trainer, checkpoints, run loading and the densification strategy handle every component the
same way and never name one. A component declares:

- its phase (`phase`, see `model.phases`: anchor, deformation, tool, exposure, illumination,
  opacity, surface, shading, loss, camera, or a phase a method declares between two of them),
  from which the model orders the components: the order of a method's config does not matter;
- its network parameters as optimiser groups with a learning-rate schedule (`param_groups`);
- its per-Gaussian attributes (`initial_attributes`), learnt with the rate `attribute_lrs` gives
  them (in `GaussianModel.params`) or, when it gives none, kept as state (e.g. the face a
  Gaussian is anchored to; in `GaussianModel.buffer_dict`, in no optimiser group): either way
  they live with the Gaussians, so densification, pruning and checkpoints carry them
  generically;
- its state for checkpoints: `nn.Module.state_dict()` (parameters and buffers);
- how it changes the Gaussians at a frame (`transform`: deformation, opacity, colour), a pure
  function of its state and the Gaussians: it changes no parameter, buffer or attribute, so
  asking twice gives the same Gaussians. State changes happen in `setup`, in `before_render`
  (once per render, before any transform: e.g. extracting a first mesh, or encoding a training
  frame once for the step's transform and losses) and in `after_step`;
- the per-Gaussian channels it adds to a render (`render_channels`) and what it derives from the
  rendered maps (`finish_render`: e.g. an unbiased depth, an exposure gain); the channels to
  show, each with its descriptor (`channel_descriptors`, see `model.channels`), which videos,
  the viewer and the report list;
- its named loss terms (`loss_names`, `losses`), computed from a `RenderContext`; their weights
  come from the method config (`MethodConfig.losses`), never from the component;
- whether it can leave the tool out of a render (`separates_tool`): a `FrameTime` asks for a
  tissue-only render with `tissue_only=True`, and such a component then drops its tool
  Gaussians (eval scores the hidden tissue on that render; `surgsplat render --tool-free`);
- its own metrics of the Gaussians at a test frame for metrics.json, with the convention of each
  (`frame_diagnostics`, e.g. tool collisions or strain);
- the other components of its method, when it builds on one of them (`bind`, e.g. Gaussians
  anchored on the mesh of the method's signed distance field);
- work between training steps (`after_step`, e.g. re-extracting a mesh every K iterations), after
  the optimiser step and densification, when every Gaussian of the next step exists;
- the capabilities it has that only some components have (`provides`: protocols of
  `model.capabilities` that the component implements itself): which Gaussians are tool, a
  corrected camera, Gaussians of its own, a gradient gate, where the canonical Gaussians are,
  an opacity factor and densification weights that densification must know of, a signed
  distance field for meshes, a relighting state, the tool's rigid motion, pose fitting of
  held-out frames. The model and the other layers find them by protocol (`providers`, `find`).

Every hook has a neutral default, so a component implements only what it contributes; only its
phase has none: every component class declares it.
A config subclass registers itself under its `kind` (the key saved in config.json), so a run's
config can be rebuilt from the file alone, including components defined outside surgsplat.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, TypeVar

from torch import Tensor, nn

from surgsplat.errors import SurgsplatError
from surgsplat.model.phases import Phase

if TYPE_CHECKING:
    from surgsplat.data.scene import Camera, Frame
    from surgsplat.model.channels import ChannelDescriptor
    from surgsplat.model.gaussians import GaussianModel
    from surgsplat.model.state import GaussianState
    from surgsplat.render.render import RenderOutput


@dataclass(frozen=True)
class FrameTime:
    """The moment a component is asked about: a frame of the clip and its time."""

    index: int  # frame index in the clip (a held-out frame's own index at test time)
    time: float  # index / number of frames, in [0, 1)
    tissue_only: bool = False  # render mode: components that separate the tool leave it out
    losses: frozenset[str] | None = None
    """The loss terms a training step's render serves (a component may leave out the channels
    only other terms need); None for every other render, which holds every channel."""
    tool_pixels: Tensor | None = field(default=None, compare=False)
    """[H, W] bool: a training step's frame's tool mask (the pixels that show no tissue); None
    for every other render."""

    def serves(self, term: str) -> bool:
        """Whether a render of this moment must hold what loss term `term` reads."""
        return self.losses is None or term in self.losses


@dataclass(frozen=True)
class SceneInfo:
    """What a component may know of the scene when its config is resolved and it is set up."""

    num_frames: int
    width: int
    height: int
    train_indices: tuple[int, ...]  # indices of the training frames


@dataclass
class SetupContext:
    """What a freshly built component sees once, before training starts."""

    scene: SceneInfo
    points: Tensor  # [M, 3] initial Gaussian means (world frame, scene units)
    scene_extent: float  # largest distance of an initial point from their centroid
    frames: Sequence[Frame]  # the training frames (images, depth, tool and FOV masks, cameras)
    added: dict[int, slice] = field(default_factory=dict)  # id(component) -> its rows of points

    def rows_added_by(self, component: Component) -> slice:
        """The rows of `points` that `component.initial_points` contributed (empty if none)."""
        return self.added.get(id(component), slice(0, 0))


@dataclass
class InitialPoints:
    """Gaussians a component adds to the scene's initial point cloud."""

    means: Tensor  # [K, 3] world frame, scene units
    colors: Tensor  # [K, 3] RGB in [0, 1]


@dataclass
class Diagnostics:
    """What a component measures of the Gaussians at one test frame, for metrics.json."""

    summed: dict[str, float] = field(default_factory=dict)  # summed over test frames (counts)
    averaged: dict[str, float] = field(default_factory=dict)  # averaged over test frames
    conventions: dict[str, str] = field(default_factory=dict)  # metric -> what it computes


@dataclass
class ParamGroup:
    """An optimiser group of a component's parameters and its learning-rate schedule."""

    name: str  # unique across the method (used in logs and to find the group again)
    params: list[nn.Parameter]
    lr: float  # learning rate at iteration 0
    lr_final: float | None = None  # when set, the rate decays exponentially to this at the end


@dataclass
class RenderContext:
    """Everything a loss term may look at: the frame, its render, and the model at that time."""

    frame: Frame
    when: FrameTime
    camera: Camera
    output: RenderOutput
    state: GaussianState  # the Gaussians as rendered (after every component's transform)
    gaussians: GaussianModel  # the canonical Gaussians and their per-Gaussian attributes
    iteration: int


class ComponentConfig:
    """Base of a component's typed dataclass config. A subclass names its `kind`:

        @dataclass
        class MyConfig(ComponentConfig, kind="my_component"):
            ...
            def build(self) -> Component: ...
    """

    kind: ClassVar[str] = ""
    registry: ClassVar[dict[str, type[ComponentConfig]]] = {}

    def __init_subclass__(cls, kind: str = "", **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if kind:
            cls.kind = kind
            ComponentConfig.registry[kind] = cls

    @classmethod
    def of_kind(cls, kind: str, where: str) -> type[ComponentConfig]:
        """The config class registered as `kind`; SurgsplatError naming `where` otherwise."""
        if kind not in cls.registry:
            raise SurgsplatError(f"{where}: unknown component kind {kind!r}; known: "
                                 f"{', '.join(sorted(cls.registry))}")
        return cls.registry[kind]

    def resolve(self, scene: SceneInfo) -> ComponentConfig:
        """This config adapted to a scene (e.g. capacity capped by the clip length); the
        resolved copy is what a run saves. Resolving twice changes nothing."""
        return self

    def build(self) -> Component:
        raise NotImplementedError(f"{type(self).__name__} must define build()")


class Component(nn.Module):
    """One piece of a method; see the module docstring. Hooks default to contributing nothing."""

    phase: ClassVar[Phase | str | None] = None
    """Where the component acts: a `model.phases.Phase` or a declared phase's name; every
    component class declares it."""
    separates_tool: ClassVar[bool] = False
    """True when `transform` leaves the tool out of renders asked with `when.tissue_only`."""
    reads_time: ClassVar[bool] = True
    """Whether the component's state or hooks depend on the clip's time (`when.time`, frame
    indices); one that does is trained on a stream only if it offers
    `capabilities.Retimable`."""
    provides: tuple[type, ...] = ()
    """The capability protocols (`model.capabilities`) this component implements itself; a
    component whose capabilities depend on its config makes it a property."""

    def bind(self, components: Mapping[str, Component]) -> None:
        """Called once with every component of the method (this one included), whenever the
        model is built (trained or loaded), before any other hook but `setup` and the initial
        points and attributes. Keep what is needed as a plain reference (not as a submodule:
        each component's state is saved once, under its own name)."""

    def before_render(self, gaussians: GaussianModel, when: FrameTime) -> None:
        """Called by `SplatModel.render` once per render, in the render's gradient mode, before
        any component's `transform`: bring the component's state up to date for `when` (e.g.
        extract a first mesh, anchor new Gaussians, or compute once what the render's
        transform and the step's losses share). The transforms that follow read that state."""

    def after_step(self, gaussians: GaussianModel, iteration: int) -> None:
        """Called without gradients after every training step (`iteration`, from 1), once the
        optimiser has stepped and densification has run."""

    def setup(self, context: SetupContext) -> None:
        """Called once on a freshly built component before training (not when a run is loaded:
        whatever it sets must live in parameters or buffers, so the state_dict restores it)."""

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        """Per-Gaussian tensors, name -> [M, ...] for the M initial points. Those that
        `attribute_lrs` names are learnt (`GaussianModel.params`); the others are state
        (`GaussianModel.buffer_dict`) that no optimiser changes. Either way a clone or split
        child copies its parent's rows, pruning drops them and checkpoints save them."""
        return {}

    def attribute_lrs(self) -> dict[str, float | tuple[float, float]]:
        """Adam learning rate of each learnt per-Gaussian attribute this component owns, by
        name: a constant rate, or (initial, final) for one that decays exponentially over the
        run."""
        return {}

    def param_groups(self) -> list[ParamGroup]:
        """Optimiser groups of the component's own (non per-Gaussian) parameters."""
        return []

    def transform(self, state: GaussianState, gaussians: GaussianModel,
                  when: FrameTime) -> GaussianState:
        """The Gaussians at `when` after this component (deform, change opacity or colour);
        pure: it changes no parameter, buffer or attribute (see `before_render`)."""
        return state

    def render_channels(self, state: GaussianState, gaussians: GaussianModel, camera: Camera,
                        when: FrameTime) -> dict[str, Tensor]:
        """Per-Gaussian values [N] or [N, k] to alpha-blend into RenderOutput.extras."""
        return {}

    def finish_render(self, output: RenderOutput, camera: Camera, when: FrameTime) -> None:
        """Derive maps from the rendered channels into output (e.g. output.extras[...])."""

    def channel_descriptors(self) -> tuple[ChannelDescriptor, ...]:
        """The channels of RenderOutput.extras this component adds (rendered or derived in
        `finish_render`) that videos, the viewer and the report show, each with its descriptor.
        Every render made without gradients must hold them."""
        return ()

    def loss_names(self) -> tuple[str, ...]:
        """Names of the loss terms this component can compute."""
        return ()

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        """Unweighted scalar loss terms, for the names in `active` (those with a weight now)."""
        return {}

    def frame_diagnostics(self, state: GaussianState, gaussians: GaussianModel,
                          when: FrameTime) -> Diagnostics | None:
        """Measurements of the Gaussians `state` at the test frame `when`, or None."""
        return None


Capability = TypeVar("Capability")


def providers(components: Iterable[Component], capability: type[Capability]
              ) -> list[Capability]:
    """The components, in order, that declare `capability` in their `provides`."""
    return [component for component in components if capability in component.provides]


def provider(components: Iterable[Component], capability: type[Capability]
             ) -> Capability | None:
    """The one component that provides `capability`, or None; SurgsplatError when several do
    (a capability of which a method can have one)."""
    found = providers(components, capability)
    if len(found) > 1:
        names = ", ".join(type(component).__name__ for component in found)
        raise SurgsplatError(f"components {names} each provide {capability.__name__}; a method "
                             "may have one")
    return found[0] if found else None

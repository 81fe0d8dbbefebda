"""The component contract: every piece of a method (a deformation field, an exposure curve, a loss,
planar Gaussians, ...) is a `Component`, configured by a typed `ComponentConfig`.

The Trainer, checkpoints, run loading and the densification strategy handle every component the
same way and never name one. A component declares:

- its phase (`phase`, see `model.phases`: anchor, deformation, tool, exposure, illumination,
  opacity, surface, shading, loss, camera), from which the model orders the components: the
  order of a method's config does not matter;
- the camera a frame is seen with (`camera`: e.g. a pose refined per frame), which
  `SplatModel.camera_at` gives every render of a frame (training steps, evaluation, videos);
- its network parameters as optimiser groups with a learning-rate schedule (`param_groups`);
- its per-Gaussian attributes (`initial_attributes`, `attribute_lrs`): they live with the Gaussians
  in `GaussianModel.params`, so densification, pruning and checkpoints carry them generically;
- its non-learnable per-Gaussian state (`initial_buffers`, e.g. the face a Gaussian is anchored
  to): buffers in `GaussianModel.buffer_dict`, which densification copies and prunes with the
  rows and checkpoints save, in no optimiser group;
- its state for checkpoints: `nn.Module.state_dict()` (parameters and buffers);
- how it changes the Gaussians at a frame (`transform`: deformation, opacity, colour), a pure
  function of its state and the Gaussians: it changes no parameter, buffer or attribute, so
  asking twice gives the same Gaussians. State changes happen in `setup`, in `before_render`
  (once per render, before any transform: e.g. extracting a first mesh, or encoding a training
  frame once for the step's transform and losses) and in `after_step`;
- which Gaussians a render keeps from which pixels' gradients (`pixel_gate`);
- the per-Gaussian channels it adds to a render (`render_channels`) and what it derives from the
  rendered maps (`finish_render`: e.g. an unbiased depth, an exposure gain); the channels to
  show, each with its descriptor (`channel_descriptors`, see `model.channels`), which videos,
  the viewer and the report list;
- its named loss terms (`loss_names`, `losses`), computed from a `RenderContext`; their weights
  come from the method config (`MethodConfig.losses`), never from the component;
- Gaussians of its own beyond the scene's initial points (`initial_points`, e.g. a tool's from
  the tool pixels' depth), which get the same per-Gaussian attributes as the others;
- which Gaussians it models as tool (`tool_members`; every other Gaussian is tissue, see
  `model.membership`), and whether it can leave them out of a render (`separates_tool`): a
  `FrameTime` asks for a tissue-only render with `tissue_only=True`, and such a component then
  drops its tool Gaussians (eval scores the hidden tissue on that render; `surgsplat render
  --tool-free`);
- the capabilities it offers other layers (`model.capabilities`): a signed distance field for
  meshes (`signed_distance_field`), a relighting state (`relighting`), the tool's rigid motion
  for its articulation (`tool_motion`);
- its own metrics of the Gaussians at a test frame for metrics.json, with the convention of each
  (`frame_diagnostics`, e.g. tool collisions or strain);
- the other components of its method, when it builds on one of them (`bind`, e.g. Gaussians
  anchored on the mesh of the method's signed distance field), and where it puts the canonical
  Gaussians when it places them itself (`canonical_means`, e.g. on the faces of that mesh);
- work between training steps (`after_step`, e.g. re-extracting a mesh every K iterations), after
  the optimiser step and densification, when every Gaussian of the next step exists;
- what densification must know of it: a factor on every Gaussian's opacity that does not depend
  on time (`opacity_factor`, e.g. an SDF-derived opacity), so that pruning, cloning and opacity
  resets act on the opacity that is rendered; and a weight on each Gaussian's screen-space
  gradient of a step (`densify_weights`, e.g. to keep occluded tissue growing).

Every hook has a neutral default, so a component implements only what it contributes; only its
phase has none: every component class declares it.
A config subclass registers itself under its `kind` (the key saved in config.json), so a run's
config can be rebuilt from the file alone, including components defined outside surgsplat.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

from torch import Tensor, nn

from surgsplat.errors import SurgsplatError
from surgsplat.model.phases import Phase

if TYPE_CHECKING:
    from surgsplat.data.scene import Camera, Frame
    from surgsplat.model.capabilities import (HeldOutPoses, Relighting, SignedDistanceField,
                                              ToolMotion)
    from surgsplat.model.channels import ChannelDescriptor
    from surgsplat.model.gaussians import GaussianModel
    from surgsplat.model.state import GaussianState
    from surgsplat.render.rasterize import PixelGate
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
    """Where the component acts: a `model.phases.Phase` or its value; every component class
    declares it."""
    separates_tool: ClassVar[bool] = False
    """True when `transform` leaves the tool out of renders asked with `when.tissue_only`."""

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

    def camera(self, camera: Camera, when: FrameTime) -> Camera:
        """The camera a render at `when` sees through, given `camera`, the one it was asked
        with (the frame's imported camera, or the viewer's): e.g. the pose with a learnt
        per-frame correction. Called by `SplatModel.camera_at`, in phase order, in the
        render's gradient mode, so the returned camera may carry gradients to the component's
        parameters (the projection differentiates the pose and K). Pure, like `transform`.
        The default returns `camera` itself."""
        return camera

    def after_step(self, gaussians: GaussianModel, iteration: int) -> None:
        """Called without gradients after every training step (`iteration`, from 1), once the
        optimiser has stepped and densification has run."""

    def setup(self, context: SetupContext) -> None:
        """Called once on a freshly built component before training (not when a run is loaded:
        whatever it sets must live in parameters or buffers, so the state_dict restores it)."""

    def initial_points(self, context: SetupContext) -> InitialPoints | None:
        """Gaussians to add to the initial points (after every component's `setup`); the
        components' `initial_attributes` then see them in `context.points`, at the rows
        `context.rows_added_by(self)`."""
        return None

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        """Learnable per-Gaussian tensors, name -> [M, ...] for the M initial points."""
        return {}

    def attribute_lrs(self) -> dict[str, float]:
        """Adam learning rate of each per-Gaussian attribute this component owns, by name."""
        return {}

    def attribute_lr_finals(self) -> dict[str, float]:
        """The rate at the end of the run of those of its attributes whose rate decays
        (exponentially, from its `attribute_lrs` rate), by name; the others keep theirs."""
        return {}

    def initial_buffers(self, context: SetupContext) -> dict[str, Tensor]:
        """Non-learnable per-Gaussian tensors, name -> [M, ...] for the M initial points
        (`GaussianModel.buffer_dict`): a clone or split child copies its parent's rows, pruning
        drops them, checkpoints save them; no optimiser changes them."""
        return {}

    def param_groups(self) -> list[ParamGroup]:
        """Optimiser groups of the component's own (non per-Gaussian) parameters."""
        return []

    def transform(self, state: GaussianState, gaussians: GaussianModel,
                  when: FrameTime) -> GaussianState:
        """The Gaussians at `when` after this component (deform, change opacity or colour);
        pure: it changes no parameter, buffer or attribute (see `before_render`)."""
        return state

    def pixel_gate(self, gaussians: GaussianModel, when: FrameTime) -> PixelGate | None:
        """Which Gaussians a render at `when` keeps from which pixels' gradients (e.g. the tool
        field keeps tissue from the frame's tool pixels), or None. At most one component of a
        model gates."""
        return None

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

    def tool_members(self, gaussians: GaussianModel) -> Tensor | None:
        """[N] bool, True = a Gaussian this component models as tool, or None when it models
        no tool. Ask `model.membership` rather than one component."""
        return None

    def signed_distance_field(self) -> SignedDistanceField | None:
        """The canonical signed distance field this component offers for meshes, or None."""
        return None

    def relighting(self) -> Relighting | None:
        """The illumination state this component lets renders change, or None."""
        return None

    def tool_motion(self) -> ToolMotion | None:
        """The rigid per-frame motion of the tool Gaussians this component offers, or None."""
        return None

    def held_out_poses(self) -> HeldOutPoses | None:
        """The pose corrections of held-out frames this component fits at test time, or None."""
        return None

    def loss_names(self) -> tuple[str, ...]:
        """Names of the loss terms this component can compute."""
        return ()

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        """Unweighted scalar loss terms, for the names in `active` (those with a weight now)."""
        return {}

    def opacity_factor(self, gaussians: GaussianModel) -> Tensor | None:
        """[N] factor in (0, 1] by which this component's `transform` multiplies every canonical
        Gaussian's opacity at all times, or None. Densification prunes, clones and resets the
        product sigmoid(opacity_logits) * factor, the opacity that is rendered."""
        return None

    def canonical_means(self, gaussians: GaussianModel) -> Tensor | None:
        """[N, 3] where this component puts the canonical Gaussians before any deformation
        (e.g. Gaussians anchored on mesh faces), differentiable in params["means"], or None when
        it leaves them at params["means"]. The mesh export measures the deformation's
        displacement from there (`SplatModel.canonical_means` asks the components in order)."""
        return None

    def densify_weights(self, context: RenderContext) -> Tensor | None:
        """[N] non-negative weight of each Gaussian's screen-space gradient in this step's
        densification statistics (0 = this step never makes it grow), or None for 1."""
        return None

    def frame_diagnostics(self, state: GaussianState, gaussians: GaussianModel,
                          when: FrameTime) -> Diagnostics | None:
        """Measurements of the Gaussians `state` at the test frame `when`, or None."""
        return None

"""Capabilities that some components have and the rest of surgsplat asks for, as protocols.

The component contract (`model.component`) holds what every component may contribute; what only
some components offer is a protocol here, which a component declares it implements by listing
it in `Component.provides` and implementing its methods itself. The model looks them up
(`SplatModel.find` for a capability one component at most offers, `SplatModel.providers` for
those several may), so that no caller looks for a concrete class or probes for attributes; a
caller that cannot do without one says so with `required`.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Protocol, TypeVar

from torch import Tensor

from surgsplat.errors import SurgsplatError

if TYPE_CHECKING:
    from surgsplat.data.scene import Camera
    from surgsplat.model.articulation import Articulation
    from surgsplat.model.component import FrameTime, InitialPoints, RenderContext, SetupContext
    from surgsplat.model.gaussians import GaussianModel
    from surgsplat.model.physics import ToolProxy
    from surgsplat.model.state import GaussianState
    from surgsplat.render.pixel_weights import PixelWeights

Offered = TypeVar("Offered")

UNIFORM = "uniform"
"""Relighting source: the mean illumination state of the training frames."""


class SignedDistanceField(Protocol):
    """A canonical signed distance field whose zero level is the tissue surface (meshes are
    extracted from it)."""

    box: Tensor
    """[2, 3] (low, high) corners of the canonical box the field describes, scene units."""

    def signed_distance(self, points: Tensor) -> Tensor:
        """[P, 3] canonical points -> [P] signed distances (scene units, > 0 in front of the
        surface, on the camera side)."""


class Relighting(Protocol):
    """An illumination state that renders can be made under instead of their own."""

    def relit(self, source: str | int) -> AbstractContextManager[None]:
        """While the block runs, render every time under illumination `source`: UNIFORM or a
        frame index (SurgsplatError for any other)."""


class HeldOutPoses(Protocol):
    """Per-frame pose corrections that can be fitted, at test time, for frames that training
    never saw."""

    def fit_held_out(self, index: int, time: float, loss: Callable[[], Tensor]) -> None:
        """Fit the correction of held-out frame `index` (at clip time `time`) so that `loss()`,
        a render of that frame with the correction scored against its image, falls; everything
        else stays as trained. Renders of the frame use the fitted correction from then on."""


class ToolMotion(Protocol):
    """The motion of the tool Gaussians (those of `ToolMembership`), frame by frame: a rigid pose
    (the shaft's), and the jaws' own angles when the motion model has joints; what the tool's
    articulation is read or estimated from."""

    def pose(self, index: int) -> tuple[Tensor, Tensor]:
        """Rotation vector [3] and translation [3] (scene units) taking the canonical tool to
        frame `index`."""

    def proxy(self, state: GaussianState, gaussians: GaussianModel) -> ToolProxy | None:
        """The tool's collision proxy in `state` (the Gaussians at one time), which the
        `collisions` diagnostic tests; None when no tool Gaussian is opaque enough."""

    def articulation(self, gaussians: GaussianModel) -> Articulation | None:
        """The tool's own joints when its motion model has them (canonical frame, every frame
        with its own jaw angles listed); None when the motion is rigid and the articulation is
        to be estimated from the frames (`model.articulation`)."""


class ToolMembership(Protocol):
    """Gaussians modelled as tool; every Gaussian that no component marks is tissue (ask
    `model.membership` or the model, not one component)."""

    def tool_members(self, gaussians: GaussianModel) -> Tensor:
        """[N] bool, True = a Gaussian this component models as tool."""


class CameraCorrection(Protocol):
    """A change of the camera a frame is seen with (e.g. a pose refined per frame), which
    `SplatModel.camera_at` applies, in phase order, to every render of a frame (training
    steps, evaluation, videos)."""

    def camera(self, camera: Camera, when: FrameTime) -> Camera:
        """The camera a render at `when` sees through, given `camera`, the one it was asked
        with. Called in the render's gradient mode, so the returned camera may carry gradients
        to the component's parameters (the projection differentiates the pose and K). Pure,
        like `Component.transform`."""


class PointSource(Protocol):
    """Gaussians of its own beyond the scene's initial points (e.g. a tool's, from the tool
    pixels' depth), which get the same per-Gaussian attributes as the others."""

    def initial_points(self, context: SetupContext) -> InitialPoints | None:
        """Gaussians to add to the initial points (after every component's `setup`); the
        components' `initial_attributes` then see them in `context.points`, at the rows
        `context.rows_added_by(self)`. None adds none."""


class GradientWeighting(Protocol):
    """How much some Gaussians learn from each pixel of a render (e.g. tissue nothing from the
    pixels that show the tool in front of it). At most one component of a model weights."""

    def gradient_weights(self, gaussians: GaussianModel, when: FrameTime) -> PixelWeights | None:
        """The per-pixel weights of some Gaussians' gradients in a render at `when`
        (`PixelWeights`), or None to weight none."""


class CanonicalPlacement(Protocol):
    """Where the canonical Gaussians are before any deformation, when a component places them
    itself (e.g. anchored on mesh faces). At most one component of a model places them."""

    def canonical_means(self, gaussians: GaussianModel) -> Tensor | None:
        """[N, 3] the canonical centres, differentiable in params["means"], or None while they
        are params["means"] (the mesh export measures the deformation's displacement from
        here)."""


class OpacityFactor(Protocol):
    """A factor that the component's transform puts on every canonical Gaussian's opacity at
    all times (e.g. an SDF-derived opacity): densification prunes, clones and resets the
    product sigmoid(opacity_logits) x every factor, the opacity that is rendered."""

    def opacity_factor(self, gaussians: GaussianModel) -> Tensor:
        """[N] factor in (0, 1]."""


class DensifyWeighting(Protocol):
    """A weight on each Gaussian's screen-space gradient in a step's densification statistics
    (e.g. to keep occluded tissue growing); the weights of several components multiply."""

    def densify_weights(self, context: RenderContext) -> Tensor | None:
        """[N] non-negative weights of this step (0 = it never makes the Gaussian grow), or
        None for 1."""


class Retimable(Protocol):
    """Time-dependent state that can follow a change of the clip's time axis: a stream whose
    clip grows maps frame i from time i / N_old to i / N_new (`train.stream`). A component
    whose transform reads `when.time` and does not offer this cannot be trained on a
    stream."""

    def retime(self, gaussians: GaussianModel, factor: float) -> None:
        """Make the state that was at time t hold at time `factor` x t, for t in [0, 1]
        (0 < factor <= 1: the clip grew; times past `factor` hold the state that was at 1)."""


def required(capability: Offered | None, missing: str) -> Offered:
    """`capability` as the model offers it; SurgsplatError(`missing`) when it offers none."""
    if capability is None:
        raise SurgsplatError(missing)
    return capability

"""Capabilities that other layers ask a method's components for, as declared interfaces.

A component offers one by returning an object with the interface from its contract hook
(`Component.signed_distance_field`, `Component.relighting`, `Component.tool_motion`,
`Component.held_out_poses`; usually
itself), and `SplatModel` asks its components in order, so that no caller looks for a concrete
class or probes for attributes; a caller that cannot do without one says so with `required`.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Protocol, TypeVar

from torch import Tensor

from surgsplat.errors import SurgsplatError

if TYPE_CHECKING:
    from surgsplat.model.gaussians import GaussianModel
    from surgsplat.model.physics import ToolProxy
    from surgsplat.model.state import GaussianState

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
    """The rigid motion of the tool Gaussians (those of `Component.tool_members`), frame by
    frame: what the tool's articulation is estimated from."""

    def pose(self, index: int) -> tuple[Tensor, Tensor]:
        """Rotation vector [3] and translation [3] (scene units) taking the canonical tool to
        frame `index`."""

    def proxy(self, state: GaussianState, gaussians: GaussianModel) -> ToolProxy | None:
        """The tool's collision proxy in `state` (the Gaussians at one time), which the
        `collisions` diagnostic tests; None when no tool Gaussian is opaque enough."""


def required(capability: Offered | None, missing: str) -> Offered:
    """`capability` as the model offers it; SurgsplatError(`missing`) when it offers none."""
    if capability is None:
        raise SurgsplatError(missing)
    return capability

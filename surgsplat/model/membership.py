"""Which Gaussians are tool and which are tissue, as the components of a method declare it.

A component that models tool Gaussians provides `ToolMembership` (`model.capabilities`) and
says which; every Gaussian that no component marks as tool is tissue. Components that treat
tissue alone (an SDF, mesh anchors, biomechanics, a volume loss) keep the method's components
from `bind` and ask here; other layers ask the model (`SplatModel.tissue_members`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from torch import Tensor

from surgsplat.model.capabilities import ToolMembership
from surgsplat.model.component import providers

if TYPE_CHECKING:
    from surgsplat.model.component import Component
    from surgsplat.model.gaussians import GaussianModel


def tool_members(components: Iterable[Component], gaussians: GaussianModel) -> Tensor | None:
    """[N] bool, True = tool: the Gaussians any of `components` models as tool; None when none
    models a tool."""
    tool = None
    for component in providers(components, ToolMembership):
        marked = component.tool_members(gaussians)
        tool = marked if tool is None else tool | marked
    return tool


def tissue_members(components: Iterable[Component], gaussians: GaussianModel) -> Tensor | None:
    """[N] bool, True = tissue: the Gaussians none of `components` models as tool; None when
    none models a tool (every Gaussian is tissue)."""
    tool = tool_members(components, gaussians)
    return None if tool is None else ~tool

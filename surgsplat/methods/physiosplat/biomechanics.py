"""PhysioSplat's biomechanical energies as loss terms (`physiosplat.txt` Section 2.3).

- "strain" (Eq. 4): ARAP strain of the tissue Gaussians at the frame's time over a canonical
  k-nearest-neighbour graph (scipy cKDTree, rebuilt whenever the Gaussians change in number,
  i.e. after densification or pruning, and every `rebuild_every` steps as the canonical means
  move): the sum over tissue Gaussians of each one's weighted sum over its neighbours, estimated
  without bias from `anchors` random tissue Gaussians (their mean times the tissue count).
- "collision" (Eq. 5): the sum over tissue Gaussians of ReLU(epsilon - Psi(mu_i(t)))^2, Psi the
  signed distance to the tool proxy at time t (balls around the tool Gaussians; the paper's
  convex hull spanned the tissue a grasper holds, see `model.physics`), fixed for the step (the
  gradient pushes the tissue, not the tool).
Both are sums over Gaussians as in the paper (whose weights are weights of sums), at one frame
per step (the paper's sum over t is the sum over steps). Lengths are in units of the scene
extent (`SetupContext.scene_extent`), so the energies, their weights and the margin epsilon
(a fraction of the extent) do not depend on the scene's unit: an energy in extent^2 is the
energy in scene units^2 divided by extent^2.
Volume preservation (Eq. 6) is the deformation field's "volume" term (`fields.deformation`),
since it needs the field's Jacobian. Tissue and tool are as the method's components declare them
(`model.membership`); without a tool, every Gaussian is tissue and there is no collision.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import torch
from torch import Tensor

from surgsplat.model.component import Component, ComponentConfig, RenderContext, SetupContext
from surgsplat.model.membership import tissue_members
from surgsplat.model.phases import Phase
from surgsplat.model.physics import (PHANTOM_EXTENT_MM, NeighbourGraph, arap_strain,
                                     collision_energy, neighbour_graph, tool_proxy)


@dataclass
class BiomechanicsConfig(ComponentConfig, kind="biomechanics"):
    """Strain and collision energies of the tissue Gaussians."""

    neighbours: int = field(default=16, metadata={"range": "[1, inf)"})
    """k of the canonical kNN graph (the paper's K = 16); >= 1."""
    anchors: int = field(default=4096, metadata={"range": "[1, inf)"})
    """Tissue Gaussians whose strain is evaluated per step (a random subset bounds the cost;
    the term is their mean times the tissue count); >= 1."""
    rebuild_every: int = field(default=100, metadata={"range": "[1, inf)"})
    """Also rebuild the kNN graph every this many steps; >= 1."""
    collision_margin: float = field(default=2.0 / PHANTOM_EXTENT_MM, metadata={"range": "[0, 1)"})
    """Epsilon of Eq. 5 as a fraction of the scene extent, in [0, 1) (the paper's 2 mm on the
    phantom: 0.0259)."""
    min_tool_opacity: float = field(default=0.1, metadata={"range": "[0, 1]"})
    """Tool Gaussians at least this opaque make up the tool proxy; in [0, 1]."""

    def build(self) -> "Biomechanics":
        return Biomechanics(self)


class Biomechanics(Component):
    """See the module docstring. extent: the scene extent (scene units), set in `setup`."""
    phase = Phase.LOSS

    def __init__(self, config: BiomechanicsConfig):
        super().__init__()
        if config.neighbours < 1 or config.anchors < 1 or config.rebuild_every < 1:
            raise ValueError("biomechanics: neighbours, anchors and rebuild_every must be >= 1")
        if not 0.0 <= config.collision_margin < 1.0:
            raise ValueError(f"biomechanics: collision_margin {config.collision_margin} is a "
                             "fraction of the scene extent, expected in [0, 1)")
        self.config = config
        self.register_buffer("extent", torch.ones(()))
        self._graph: NeighbourGraph | None = None
        self._graph_key: tuple[int, int] = (-1, -1)  # (Gaussian count, rebuild period index)
        self._method: tuple[Component, ...] = ()  # the method's components (plain references)

    def bind(self, components: Mapping[str, Component]) -> None:
        self._method = tuple(components.values())

    def setup(self, context: SetupContext) -> None:
        self.extent.fill_(max(context.scene_extent, 1e-12))

    def loss_names(self) -> tuple[str, ...]:
        return ("strain", "collision")

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        tissue = tissue_members(self._method, context.gaussians)
        if tissue is None:
            tissue = torch.ones(context.gaussians.num_gaussians, dtype=torch.bool)
        terms = {}
        if "strain" in active:
            terms["strain"] = self.strain(context, tissue)
        if "collision" in active:
            terms["collision"] = self.collision(context, tissue)
        return terms

    def strain(self, context: RenderContext, tissue: Tensor) -> Tensor:
        """Eq. 4 at the frame's time, summed over the tissue Gaussians (estimated from
        `anchors` random ones), in units of extent^2."""
        gaussians = context.gaussians
        key = (gaussians.num_gaussians, context.iteration // self.config.rebuild_every)
        if self._graph is None or key != self._graph_key:
            self._graph = neighbour_graph(gaussians.params["means"], tissue,
                                          self.config.neighbours)
            self._graph_key = key
        graph = self._graph
        count = graph.members.shape[0]
        if count == 0 or graph.neighbours.shape[1] == 0:
            return context.state.means.sum() * 0.0
        rows = torch.randperm(count)[:self.config.anchors]
        energy = arap_strain(context.state.means, gaussians.params["means"], graph, rows)
        return energy.mean() * count / self.extent.square()

    def collision(self, context: RenderContext, tissue: Tensor) -> Tensor:
        """Eq. 5 at the frame's time, summed over the tissue Gaussians, in units of extent^2."""
        means = context.state.means
        state = context.state
        proxy = None if tissue.all() else tool_proxy(means, state.scales, state.opacities,
                                                     ~tissue, self.config.min_tool_opacity)
        if proxy is None:
            return means.sum() * 0.0
        margin = self.config.collision_margin * float(self.extent)
        sdf = proxy.sdf(means[tissue], 2 * margin)
        return collision_energy(sdf, margin).sum() / self.extent.square()

"""PhysioSplat's biomechanical energies as loss terms (`physiosplat.txt` Section 2.3).

- "strain" (Eq. 4): ARAP strain of the tissue Gaussians at the frame's time over a canonical
  k-nearest-neighbour graph (scipy cKDTree, rebuilt whenever the Gaussians change in number,
  i.e. after densification or pruning, and every `rebuild_every` steps as the canonical means
  move); the mean over `anchors` random tissue Gaussians of each one's weighted sum.
- "collision" (Eq. 5): the mean over tissue Gaussians of ReLU(epsilon - Psi(mu_i(t)))^2, Psi the
  signed distance to the convex hull of the tool Gaussians at time t (`model.physics`), whose
  planes are fixed for the step (the gradient pushes the tissue, not the tool).
Volume preservation (Eq. 6) is the deformation field's "volume" term (`fields.deformation`),
since it needs the field's Jacobian. Tissue and tool come from the semantic logit of the tool
field; without one, every Gaussian is tissue and there is no collision.
Means are per Gaussian (not sums as in the paper), so the weights do not scale with N.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from surgsplat.model.component import Component, ComponentConfig, RenderContext
from surgsplat.model.physics import (NeighbourGraph, arap_strain, collision_energy,
                                     neighbour_graph, tissue_members, tool_hull)


@dataclass
class BiomechanicsConfig(ComponentConfig, kind="biomechanics"):
    """Strain and collision energies of the tissue Gaussians."""

    neighbours: int = 16
    """k of the canonical kNN graph (the paper's K = 16)."""
    anchors: int = 4096
    """Tissue Gaussians whose strain is evaluated per step (a random subset bounds the cost)."""
    rebuild_every: int = 100
    """Also rebuild the kNN graph every this many steps."""
    collision_margin: float = 2.0
    """Epsilon of Eq. 5, scene units (the paper's 2 mm)."""
    min_hull_opacity: float = 0.1
    """Tool Gaussians at least this opaque span the tool hull."""

    def build(self) -> "Biomechanics":
        return Biomechanics(self)


class Biomechanics(Component):
    """See the module docstring."""

    def __init__(self, config: BiomechanicsConfig):
        super().__init__()
        self.config = config
        self._graph: NeighbourGraph | None = None
        self._graph_key: tuple[int, int] = (-1, -1)  # (Gaussian count, rebuild period index)

    def loss_names(self) -> tuple[str, ...]:
        return ("strain", "collision")

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        params = context.gaussians.params
        tissue = tissue_members(params)
        if tissue is None:
            tissue = torch.ones(context.gaussians.num_gaussians, dtype=torch.bool)
        means = context.state.means
        terms = {}
        if "strain" in active:
            terms["strain"] = self.strain(context, tissue)
        if "collision" in active:
            terms["collision"] = means.sum() * 0.0
            hull = None if tissue.all() else tool_hull(means, context.state.opacities, ~tissue,
                                                       self.config.min_hull_opacity)
            if hull is not None:
                margin = self.config.collision_margin
                sdf = hull.sdf(means[tissue], 2 * margin)
                terms["collision"] = collision_energy(sdf, margin).mean()
        return terms

    def strain(self, context: RenderContext, tissue: Tensor) -> Tensor:
        """Mean Eq. 4 strain of `anchors` random tissue Gaussians at the frame's time."""
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
        return arap_strain(context.state.means, gaussians.params["means"], graph, rows).mean()

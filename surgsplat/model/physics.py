"""Physical quantities of Gaussian sets, as plain tensor functions.

- The tool proxy Psi: a signed distance to the tool, the union of balls around the tool
  Gaussians' centres, each of its Gaussian's smallest scale (the thickness of the tool's skin
  of Gaussians, where a Gaussian's largest scale can be far longer),
  Psi(x) = min_k (|x - c_k| - r_k), differentiable in x. Not the tool's convex hull: a grasper
  touching tissue spans a hull over the tissue it holds, so a hull would count that tissue as
  inside the tool (measurements: docs/methods/shared-components.md).
- ARAP (as-rigid-as-possible) strain over a canonical k-nearest-neighbour graph (scipy's
  cKDTree), with the stiffness weights w_ij = exp(-|d_ij(0)|^2 / zeta^2), zeta the mean
  neighbour distance.

Which Gaussians are tool and which tissue is the components' to say (`model.membership`).

All lengths are in scene units.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

PHANTOM_EXTENT_MM = 77.35
"""Scene extent (largest distance of an initial point from their centroid) of the full pulling
phantom, mm: the length by which lengths given in millimetres (such as a 2 mm margin) become
fractions of the scene extent (2 mm = 0.0259 of it)."""


@dataclass
class ToolProxy:
    """The tool as a union of balls (see the module docstring)."""

    centres: Tensor  # [K, 3] tool Gaussians' centres at one time
    radii: Tensor  # [K] their smallest scales

    candidates: int = 8
    """Nearest centres among which Psi's minimum is looked for."""

    def sdf(self, x: Tensor, clear: float) -> Tensor:
        """[N, 3] -> [N] Psi(x) = min_k (|x - c_k| - r_k) over the `candidates` nearest centres;
        points farther than `clear` from every ball get `clear` (at least that far from the
        tool), which bounds the cost to the points near the tool."""
        from scipy.spatial import cKDTree

        values = torch.full((x.shape[0],), float(clear), dtype=x.dtype)
        reach = float(clear) + float(self.radii.max())
        lo, hi = self.centres.min(dim=0).values - reach, self.centres.max(dim=0).values + reach
        near = ((x.detach() >= lo) & (x.detach() <= hi)).all(dim=1).nonzero()[:, 0]
        if near.numel() == 0:
            return values
        k = min(self.candidates, self.centres.shape[0])
        _, index = cKDTree(self.centres.double().numpy()).query(
            x.detach()[near].double().numpy(), k=k, distance_upper_bound=reach)
        index = torch.from_numpy(index.reshape(near.shape[0], k))
        found = index < self.centres.shape[0]  # cKDTree marks "none within reach" by K
        index = index.clamp(max=self.centres.shape[0] - 1)
        distance = (x[near][:, None] - self.centres[index]).norm(dim=-1) - self.radii[index]
        distance = torch.where(found, distance, torch.full_like(distance, float(clear)))
        return values.index_put((near,), distance.min(dim=1).values.clamp(max=float(clear)))


@dataclass
class NeighbourGraph:
    """A canonical k-nearest-neighbour graph of M points (rows of a chosen subset)."""

    members: Tensor  # [M] long: index of each graph point among all Gaussians
    neighbours: Tensor  # [M, k] long: indices (among all Gaussians) of each point's neighbours
    weights: Tensor  # [M, k] stiffness weights exp(-|mu_i(0) - mu_j(0)|^2 / zeta^2)


def neighbour_graph(points: Tensor, members: Tensor, k: int) -> NeighbourGraph:
    """The k-nearest-neighbour graph (cKDTree) among the canonical points [N, 3] selected by the
    bool mask `members` [N]; zeta = the mean distance to the k neighbours."""
    from scipy.spatial import cKDTree

    index = members.nonzero()[:, 0]
    chosen = points.detach()[index].double().cpu().numpy()
    k = min(k, max(len(chosen) - 1, 0))
    if k == 0:
        empty = torch.zeros(len(chosen), 0)
        return NeighbourGraph(index, empty.long(), empty)
    distances, rows = cKDTree(chosen).query(chosen, k=k + 1,
                                            workers=torch.get_num_threads())
    rest = torch.from_numpy(distances[:, 1:]).to(points.dtype)
    zeta = rest.mean().clamp_min(1e-12)
    return NeighbourGraph(index, index[torch.from_numpy(rows[:, 1:])],
                          torch.exp(-(rest / zeta).square()))


def arap_strain(means: Tensor, canonical: Tensor, graph: NeighbourGraph,
                rows: Tensor | None = None) -> Tensor:
    """ARAP strain per graph point: sum_j w_ij (|mu_i(t) - mu_j(t)| - |mu_i(0) - mu_j(0)|)^2,
    for the deformed means [N, 3] and the canonical means [N, 3] (rest lengths, no gradient) of
    all Gaussians; `rows` [S] picks graph points (default all) -> [S]."""
    rows = torch.arange(graph.members.shape[0]) if rows is None else rows
    centres, neighbours = graph.members[rows], graph.neighbours[rows]  # [S], [S, k]
    rest = _lengths(canonical.detach(), centres, neighbours)
    length = _lengths(means, centres, neighbours)
    return (graph.weights[rows] * (length - rest).square()).sum(dim=1)


def _lengths(points: Tensor, centres: Tensor, neighbours: Tensor) -> Tensor:
    """[S, k] distances from points[centres] [S] to points[neighbours] [S, k]."""
    offsets = points[neighbours] - points[centres][:, None]  # [S, k, 3]
    return offsets.square().sum(-1).add(1e-12).sqrt()


def collision_energy(sdf: Tensor, margin: float) -> Tensor:
    """Collision penalty per point: ReLU(margin - Psi)^2 for signed distances Psi [N] -> [N]."""
    return torch.relu(margin - sdf).square()


def tool_proxy(means: Tensor, scales: Tensor, opacities: Tensor, tool: Tensor,
               min_opacity: float) -> ToolProxy | None:
    """The tool proxy of the tool Gaussians (bool [N]) at least `min_opacity` opaque, from their
    means [N, 3] and scales [N, 3] at one time (no gradient); None without such Gaussians."""
    chosen = tool & (opacities.detach() >= min_opacity)
    if not chosen.any():
        return None
    return ToolProxy(means.detach()[chosen], scales.detach()[chosen].min(dim=1).values)

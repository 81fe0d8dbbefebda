"""Physical quantities of Gaussian sets (PhysioSplat Section 2.3), as plain tensor functions.

- The tool proxy: the convex hull of the tool Gaussians' means as facet planes, and its signed
  distance Psi(x) = max_f (n_f . x + b_f): exact (negative) inside the hull, a lower bound of the
  distance (positive) outside; differentiable in x.
- ARAP strain (Eq. 4) over a canonical k-nearest-neighbour graph (scipy's cKDTree), with the
  stiffness weights w_ij = exp(-|d_ij(0)|^2 / zeta^2), zeta the mean neighbour distance.
- Tissue / tool membership from the per-Gaussian semantic logit s: p = sigmoid(s) is the tissue
  probability, and a Gaussian is tissue when p >= tau = 0.5 (the paper's threshold), i.e. s >= 0.

All lengths are in scene units.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

PHANTOM_EXTENT_MM = 77.35
"""Scene extent (largest distance of an initial point from their centroid) of the full pulling
phantom, mm: the length by which the paper's millimetre values (its 2 mm margin) become
fractions of the scene extent (2 mm = 0.0259 of it)."""

SEMANTIC_KEY = "semantic_logit"
"""Per-Gaussian attribute holding the semantic logit s ([N]; sigmoid(s) = tissue probability)."""


def tissue_members(params) -> Tensor | None:
    """[N] bool, True = tissue Gaussian (sigmoid(s) >= 0.5), from a params dict holding
    SEMANTIC_KEY; None when there is no semantic logit (every Gaussian is tissue)."""
    logits = params.get(SEMANTIC_KEY)
    return None if logits is None else logits.detach() >= 0.0


@dataclass
class ToolHull:
    """The convex hull of a point set: its facet planes and its axis-aligned bounds."""

    planes: Tensor  # [F, 4] unit outward normal and offset: n . x + b <= 0 inside
    lo: Tensor  # [3] lower corner of the points' bounding box
    hi: Tensor  # [3] upper corner

    def sdf(self, x: Tensor, clear: float) -> Tensor:
        """[N, 3] -> [N] signed distance proxy max_f (n_f . x + b_f); points farther than
        `clear` outside the bounding box are not evaluated and get `clear` (at least that far
        from the hull), which bounds the cost to the points near the tool."""
        near = ((x.detach() >= self.lo - clear) & (x.detach() <= self.hi + clear)).all(dim=1)
        values = torch.full((x.shape[0],), float(clear), dtype=x.dtype)
        if near.any():
            values = values.index_put((near,), hull_sdf(x[near], self.planes))
        return values


def hull_planes(points: Tensor) -> Tensor | None:
    """[K, 3] points -> [F, 4] facet planes (unit outward normal, offset) of their convex hull,
    with n . x + b <= 0 inside; None when the points span no volume (fewer than 4, or flat)."""
    from scipy.spatial import ConvexHull, QhullError

    array = points.detach().double().cpu().numpy()
    if array.shape[0] < 4:
        return None
    try:
        hull = ConvexHull(array)
    except QhullError:
        return None
    return torch.from_numpy(hull.equations).to(points.dtype)


def hull_sdf(x: Tensor, planes: Tensor) -> Tensor:
    """[N, 3] points, [F, 4] hull planes -> [N] signed distance proxy max_f (n_f . x + b_f)."""
    return (x @ planes[:, :3].T + planes[:, 3]).max(dim=1).values


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
    distances, rows = cKDTree(chosen).query(chosen, k=k + 1, workers=-1)
    rest = torch.from_numpy(distances[:, 1:]).to(points.dtype)
    zeta = rest.mean().clamp_min(1e-12)
    return NeighbourGraph(index, index[torch.from_numpy(rows[:, 1:])],
                          torch.exp(-(rest / zeta).square()))


def arap_strain(means: Tensor, canonical: Tensor, graph: NeighbourGraph,
                rows: Tensor | None = None) -> Tensor:
    """Eq. 4 per graph point: sum_j w_ij (|mu_i(t) - mu_j(t)| - |mu_i(0) - mu_j(0)|)^2, for the
    deformed means [N, 3] and the canonical means [N, 3] (rest lengths, no gradient) of all
    Gaussians; `rows` [S] picks graph points (default all) -> [S]."""
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
    """Eq. 5 per point: ReLU(margin - Psi)^2 for signed distances Psi [N] -> [N]."""
    return torch.relu(margin - sdf).square()


def tool_hull(means: Tensor, opacities: Tensor, tool: Tensor, min_opacity: float,
              max_points: int = 512) -> ToolHull | None:
    """The convex hull of the tool Gaussians (bool [N]) at least `min_opacity` opaque, from
    their means [N, 3] at one time (no gradient), spanned by at most `max_points` of them (an
    evenly strided subset, which keeps the facet count small); None without a hull."""
    chosen = means.detach()[tool & (opacities.detach() >= min_opacity)]
    if chosen.shape[0] > max_points:
        chosen = chosen[torch.linspace(0, chosen.shape[0] - 1, max_points).long()]
    planes = hull_planes(chosen)
    if planes is None:
        return None
    return ToolHull(planes, chosen.min(dim=0).values, chosen.max(dim=0).values)

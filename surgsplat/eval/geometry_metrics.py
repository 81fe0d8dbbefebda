"""Geometry metrics: a reconstructed point set against a ground-truth surface, and depth error.

Point sets and meshes are in millimetres (the phantom's unit); all distances are Euclidean, in mm.
Given reconstructed points P [N, 3] and a ground-truth triangle mesh, with S the mesh's surface
sampled uniformly by area (`sample_surface`, seeded):

- p2s(p): the exact distance from p to the nearest point of the mesh surface (point-to-triangle,
  not point-to-vertex). `p2s_mean_mm`, `p2s_median_mm`, `p2s_p95_mm` are the mean, median and
  95th percentile (linear interpolation) of p2s over P.
- `chamfer_mm` (point-set Chamfer distance, Fan et al. 2017, unsquared):
  0.5 * (mean over p in P of min_s |p - s|  +  mean over s in S of min_p |s - p|).
- `fscore_1mm` (Tatarchenko et al. 2019): precision = share of P with p2s <= 1 mm; recall = share
  of S within 1 mm of its nearest point of P; F = 2 P R / (P + R), and 0 when both are 0.

Weighted statistics of per-point distances d_i with weights w_i >= 0 (`weighted_mean_median`):
the mean sum w_i d_i / sum w_i, and the weighted median, the smallest d_k (in ascending order)
whose cumulative weight reaches half the total (the lower weighted median; equal weights give the
lower of the two middle values).

Accepts numpy arrays or CPU tensors and computes in float64 with numpy / SciPy.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from torch import Tensor

from surgsplat.image.depth import valid_depth_pixels

FSCORE_THRESHOLD_MM = 1.0
GEOMETRY_KEYS = ("chamfer_mm", "p2s_mean_mm", "p2s_median_mm", "p2s_p95_mm", "fscore_1mm")
"""The metrics `geometry_metrics` gives; metrics.json has them of the rendered depth back-projected
(no prefix) and of the exported mesh (`mesh_`)."""
_CANDIDATES = 8  # nearest triangle centroids checked exactly before the exactness test
_CHUNK = 1 << 20  # point-triangle pairs evaluated at once


def _as_points(values, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or len(array) == 0:
        raise ValueError(f"{name}: expected a non-empty [N, 3] array, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: holds NaN or infinite values")
    return array


def _as_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    vertices = _as_points(vertices, "vertices")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces: expected a non-empty [F, 3] index array, got shape {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer) or not (
            0 <= faces.min() and faces.max() < len(vertices)):
        raise ValueError(f"faces: expected integer indices into {len(vertices)} vertices")
    return vertices, faces.astype(np.int64)


def _rowdot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", x, y)


def _segment_distance(offset: np.ndarray, edge: np.ndarray, along: np.ndarray,
                      length2: np.ndarray) -> np.ndarray:
    """[M] distances from points to segments, from the point's offset from the segment start
    [M, 3], the segment vector [M, 3], their dot product [M] and the squared length [M]."""
    t = np.clip(along / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    return np.linalg.norm(offset - t[:, None] * edge, axis=1)


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """[M] exact distances from points [M, 3] to triangles [M, 3, 3] (row i to row i).

    The nearest point of a triangle is the point's projection on the triangle's plane when its
    barycentric coordinates are all >= 0, else a point of one of the three edges; degenerate
    (zero-area) triangles reduce to their edges.
    """
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    ab, ac, ap = b - a, c - a, points - a  # [M, 3]
    d00, d01, d11 = _rowdot(ab, ab), _rowdot(ab, ac), _rowdot(ac, ac)
    d20, d21 = _rowdot(ap, ab), _rowdot(ap, ac)
    denom = d00 * d11 - d01 * d01  # squared parallelogram area
    nondegenerate = denom > 1e-12 * d00 * d11
    safe = np.where(nondegenerate, denom, 1.0)
    v = (d11 * d20 - d01 * d21) / safe
    w = (d00 * d21 - d01 * d20) / safe
    inside = nondegenerate & (v >= 0) & (w >= 0) & (v + w <= 1)
    plane = np.linalg.norm(ap - v[:, None] * ab - w[:, None] * ac, axis=1)
    bc, bp = c - b, points - b
    edges = np.minimum(np.minimum(_segment_distance(ap, ab, d20, d00),
                                  _segment_distance(ap, ac, d21, d11)),
                       _segment_distance(bp, bc, _rowdot(bp, bc), _rowdot(bc, bc)))
    return np.where(inside, plane, edges)


def _pair_distances(points: np.ndarray, triangles: np.ndarray, owner: np.ndarray,
                    face: np.ndarray) -> np.ndarray:
    """[K] distances from points[owner] to triangles[face], evaluated in bounded chunks."""
    out = np.empty(len(owner))
    for start in range(0, len(owner), _CHUNK):
        part = slice(start, start + _CHUNK)
        out[part] = point_triangle_distance(points[owner[part]], triangles[face[part]])
    return out


def point_to_surface(points, vertices, faces) -> np.ndarray:
    """[N] exact distance from each point to the nearest point of the mesh surface.

    Candidates are shortlisted with a k-d tree over triangle centroids: the nearest few triangles
    give an upper bound d; a triangle whose centroid c lies farther than d + r from the point
    (r = the largest centroid-to-vertex distance of any triangle) cannot be nearer, so points
    whose bound is not already certified by the shortlist are re-checked against every triangle
    whose centroid lies within d + r. The result is exact, not approximate.
    """
    points = _as_points(points, "points")
    vertices, faces = _as_mesh(vertices, faces)
    triangles = vertices[faces]  # [F, 3, 3]
    centroids = triangles.mean(axis=1)  # [F, 3]
    reach = np.linalg.norm(triangles - centroids[:, None], axis=2).max(axis=1)  # [F]
    max_reach = reach.max()
    tree = cKDTree(centroids)
    k = min(_CANDIDATES, len(faces))
    centroid_dist, nearest = tree.query(points, k=k)
    centroid_dist = centroid_dist.reshape(len(points), k)  # [N, k]
    nearest = nearest.reshape(len(points), k)
    owner = np.repeat(np.arange(len(points)), k)
    best = _pair_distances(points, triangles, owner, nearest.ravel()).reshape(-1, k).min(axis=1)
    if k == len(faces):
        return best
    unsure = np.flatnonzero(best + max_reach > centroid_dist[:, -1])
    if len(unsure):
        hits = tree.query_ball_point(points[unsure], r=best[unsure] + max_reach)
        counts = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))
        face = np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])
        owner = np.repeat(unsure, counts)
        # skip triangles whose own lower bound |p - c| - reach already exceeds the best distance
        lower = np.linalg.norm(points[owner] - centroids[face], axis=1) - reach[face]
        keep = lower <= best[owner]
        owner, face = owner[keep], face[keep]
        np.minimum.at(best, owner, _pair_distances(points, triangles, owner, face))
    return best


def sample_surface(vertices, faces, count: int, seed: int = 0) -> np.ndarray:
    """[count, 3] points uniformly distributed over the mesh surface by area (seeded)."""
    vertices, faces = _as_mesh(vertices, faces)
    triangles = vertices[faces]  # [F, 3, 3]
    areas = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0],
                                          triangles[:, 2] - triangles[:, 0]), axis=1)
    if areas.sum() <= 0:
        raise ValueError("the mesh has zero surface area")
    rng = np.random.default_rng(seed)
    face = rng.choice(len(faces), size=count, p=areas / areas.sum())
    root = np.sqrt(rng.random(count))
    second = rng.random(count)
    weights = np.stack([1 - root, root * (1 - second), root * second], axis=1)  # [count, 3]
    return np.einsum("ij,ijk->ik", weights, triangles[face])


def chamfer_mm(points, gt_points) -> float:
    """Symmetric Chamfer distance: the mean of the two directed mean nearest-neighbour distances."""
    points = _as_points(points, "points")
    gt_points = _as_points(gt_points, "gt_points")
    forward = cKDTree(gt_points).query(points)[0]
    backward = cKDTree(points).query(gt_points)[0]
    return float(0.5 * (forward.mean() + backward.mean()))


def geometry_metrics(points, vertices, faces, seed: int = 0,
                     num_samples: int = 100_000) -> dict[str, float]:
    """Reconstructed points [N, 3] (mm) against a GT mesh: the five metrics of the module doc.

    S is `num_samples` area-uniform samples of the mesh drawn with `seed`.
    """
    points = _as_points(points, "points")
    samples = sample_surface(vertices, faces, num_samples, seed)  # [S, 3]
    p2s = point_to_surface(points, vertices, faces)  # [N]
    to_points = cKDTree(points).query(samples)[0]  # [S]
    precision = float((p2s <= FSCORE_THRESHOLD_MM).mean())
    recall = float((to_points <= FSCORE_THRESHOLD_MM).mean())
    total = precision + recall
    return {
        "chamfer_mm": chamfer_mm(points, samples),
        "p2s_mean_mm": float(p2s.mean()),
        "p2s_median_mm": float(np.median(p2s)),
        "p2s_p95_mm": float(np.percentile(p2s, 95)),
        "fscore_1mm": 2 * precision * recall / total if total > 0 else 0.0,
    }


def weighted_mean_median(values, weights) -> tuple[float, float]:
    """Weighted mean and lower weighted median (module docstring) of values [N] with weights
    [N] >= 0 whose sum is positive."""
    values = np.asarray(values, dtype=np.float64).ravel()
    weights = np.asarray(weights, dtype=np.float64).ravel()
    if values.shape != weights.shape or len(values) == 0:
        raise ValueError(f"expected values and weights of one non-empty shape [N], got "
                         f"{values.shape} and {weights.shape}")
    if not (np.isfinite(weights).all() and (weights >= 0).all() and weights.sum() > 0):
        raise ValueError("weights must be finite, >= 0 and not all 0")
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    median = values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])]
    return float(np.dot(weights, values) / weights.sum()), float(median)


def depth_rmse(pred_depth: Tensor, gt_depth: Tensor, tissue: Tensor) -> float:
    """Root-mean-square depth error in the scene unit, over tissue pixels with gt_depth > 0.

    pred_depth, gt_depth: [H, W] in the scene's unit (mm for the phantom); tissue: bool [H, W].
    """
    valid = valid_depth_pixels(pred_depth, gt_depth, tissue)
    if not valid.any():
        raise ValueError("no tissue pixel has a positive ground-truth depth")
    error = pred_depth[valid].double() - gt_depth[valid].double()
    return float(error.square().mean().sqrt())

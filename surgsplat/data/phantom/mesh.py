"""The ground-truth tissue mesh: a camera-space triangle grid over the whole view.

Vertices are the tissue hits of the rays through every `step`-th pixel centre (and the last
row and column), so each vertex projects exactly onto a pixel centre and its z equals that
pixel's tissue depth. Triangles are wound to face the camera.
"""

from __future__ import annotations

import numpy as np


def grid_indices(size: int, step: int) -> np.ndarray:
    """Pixel indices 0, step, 2 step, ... plus the last pixel, sorted and unique."""
    return np.unique(np.append(np.arange(0, size, step), size - 1))


def grid_mesh(tissue_depth: np.ndarray, xn: np.ndarray, yn: np.ndarray, step: int,
              colors: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(vertices [V, 3] mm, faces [F, 3], vertex colours [V, 3] or None) of the tissue surface
    from its depth [H, W] mm, the pixel rays (xn, yn) [H, W] and colours [H, W, 3] per pixel."""
    rows = grid_indices(tissue_depth.shape[0], step)
    cols = grid_indices(tissue_depth.shape[1], step)
    z = tissue_depth[np.ix_(rows, cols)]  # [R, C]
    vertices = np.stack([z * xn[np.ix_(rows, cols)], z * yn[np.ix_(rows, cols)], z],
                        axis=-1).reshape(-1, 3)
    ids = np.arange(len(rows) * len(cols)).reshape(len(rows), len(cols))
    top_left, top_right = ids[:-1, :-1].ravel(), ids[:-1, 1:].ravel()
    bottom_left, bottom_right = ids[1:, :-1].ravel(), ids[1:, 1:].ravel()
    # Image x right, y down, camera z forward: (a, below a, right of a) winds towards -z.
    faces = np.concatenate([np.stack([top_left, bottom_left, top_right], axis=1),
                            np.stack([top_right, bottom_left, bottom_right], axis=1)])
    vertex_colors = None if colors is None else colors[np.ix_(rows, cols)].reshape(-1, 3)
    return vertices, faces, vertex_colors

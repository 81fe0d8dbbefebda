"""Pinhole pixel geometry: the one generator of pixel rays, back-projection of depth maps, and
normals of the surface a depth map describes.

Pixel (u, v) = (column, row) is taken at its centre (u + 0.5, v + 0.5); cameras follow the OpenCV
convention (x right, y down, z forward), and depth is the z-coordinate in the camera frame, in the
scene's unit.
"""

from __future__ import annotations

import torch
from torch import Tensor


def pixel_rays(K: Tensor, width: int, height: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """[H, W, 3] camera-space rays K^-1 [u + 0.5, v + 0.5, 1] through the pixel centres
    (z component 1), for pinhole intrinsics K [3, 3]."""
    K = K.to(dtype)
    u = torch.arange(width, dtype=dtype) + 0.5
    v = torch.arange(height, dtype=dtype) + 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return torch.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1],
                        torch.ones_like(uu)], dim=-1)


def backproject_camera(depth: Tensor, K: Tensor) -> Tensor:
    """[H, W, 3] camera-space points (OpenCV axes) of every pixel centre (x + 0.5, y + 0.5) at
    its z-depth [H, W] (scene units), for pinhole intrinsics K [3, 3]."""
    height, width = depth.shape
    return pixel_rays(K, width, height, depth.dtype) * depth[..., None]


def depth_normals(depth: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:
    """Camera-space normals of the surface a depth map [H, W] describes (EndoPlanar Eq. 7).

    Each pixel's four neighbours are back-projected; the normal is the normalised cross product
    (P_right - P_left) x (P_down - P_up), oriented to face away from the camera (n . P > 0 at the
    pixel's point P, the convention of the rendered planar normals). Returns normals [H, W, 3] and valid [H, W] bool:
    interior pixels whose four neighbours all have depth > 0 and a non-degenerate cross product.
    """
    points = backproject_camera(depth, K)  # [H, W, 3]
    valid = torch.zeros(depth.shape, dtype=torch.bool, device=depth.device)
    horizontal = points[1:-1, 2:] - points[1:-1, :-2]  # [H-2, W-2, 3]
    vertical = points[2:, 1:-1] - points[:-2, 1:-1]
    cross = torch.linalg.cross(horizontal, vertical, dim=-1)
    length = cross.norm(dim=-1, keepdim=True)
    normal = cross / length.clamp_min(1e-12)
    facing = (normal * points[1:-1, 1:-1]).sum(-1, keepdim=True)
    normal = torch.where(facing < 0, -normal, normal)
    positive = depth > 0
    neighbours = positive[1:-1, 2:] & positive[1:-1, :-2] & positive[2:, 1:-1] & positive[:-2, 1:-1]
    normals = torch.nn.functional.pad(normal.permute(2, 0, 1), (1, 1, 1, 1)).permute(1, 2, 0)
    valid[1:-1, 1:-1] = neighbours & (length[..., 0] > 1e-12)
    return normals, valid

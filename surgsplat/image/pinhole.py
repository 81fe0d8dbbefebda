"""Pinhole pixel geometry: the one generator of pixel rays, back-projection of depth maps, and
normals of the surface a depth map describes.

Pixel (u, v) = (column, row) is taken at its centre (u + 0.5, v + 0.5); cameras follow the OpenCV
convention (x right, y down, z forward), and depth is the z-coordinate in the camera frame, in the
scene's unit.
"""

from __future__ import annotations

import torch
from torch import Tensor


def pixel_ray_axes(K: Tensor, width: int, height: int,
                   dtype: torch.dtype = torch.float32) -> tuple[Tensor, Tensor]:
    """The two varying components of the pixel rays K^-1 [u + 0.5, v + 0.5, 1]: x [W] of each
    column u and y [H] of each row v (the ray of pixel (u, v) is (x[u], y[v], 1))."""
    K = K.to(dtype)
    u = torch.arange(width, dtype=dtype) + 0.5
    v = torch.arange(height, dtype=dtype) + 0.5
    return (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]


def pixel_rays(K: Tensor, width: int, height: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """[H, W, 3] camera-space rays K^-1 [u + 0.5, v + 0.5, 1] through the pixel centres
    (z component 1), for pinhole intrinsics K [3, 3]."""
    x, y = pixel_ray_axes(K, width, height, dtype)
    return torch.stack([x.expand(height, width), y[:, None].expand(height, width),
                        torch.ones(height, width, dtype=x.dtype)], dim=-1)


def backproject_camera(depth: Tensor, K: Tensor) -> Tensor:
    """[H, W, 3] camera-space points (OpenCV axes) of every pixel centre (x + 0.5, y + 0.5) at
    its z-depth [H, W] (scene units), for pinhole intrinsics K [3, 3]."""
    height, width = depth.shape
    return pixel_rays(K, width, height, depth.dtype) * depth[..., None]


def backproject(depth: Tensor, K: Tensor, mask: Tensor,
                camera_to_world: Tensor | None = None) -> Tensor:
    """[M, 3] points of the pixels where mask is True and depth > 0: in camera space, or in the
    world frame when camera_to_world [4, 4] is given.

    depth: [H, W] z-depth in the scene's unit; K: [3, 3] pinhole intrinsics (fx, fy, cx, cy);
    mask: bool [H, W]. Rows follow the pixel order of `depth[mask & (depth > 0)]`.
    """
    if depth.dim() != 2 or mask.shape != depth.shape or mask.dtype != torch.bool:
        raise ValueError(f"expected depth [H, W] and a bool mask of the same shape, got "
                         f"{tuple(depth.shape)} and {mask.dtype} {tuple(mask.shape)}")
    chosen = mask & (depth > 0)
    height, width = depth.shape
    points = pixel_rays(K, width, height, depth.dtype)[chosen] * depth[chosen][:, None]
    if camera_to_world is None:
        return points
    pose = camera_to_world.to(points.dtype)
    return points @ pose[:3, :3].T + pose[:3, 3]


def project_points(points: Tensor, K: Tensor, world_to_camera: Tensor) -> tuple[Tensor, Tensor]:
    """World points [P, 3] -> (pixel [P, 2] as (column, row) indices of the pixel each falls in,
    int64, possibly outside the image; z-depth [P] in the camera frame, scene units). The
    inverse of `backproject` at pixel centres. world_to_camera: [4, 4]; K: [3, 3]."""
    pose = world_to_camera.to(points.dtype)
    camera = points @ pose[:3, :3].T + pose[:3, 3]
    z = camera[:, 2]
    safe_z = torch.where(z > 0, z, torch.ones_like(z))
    K = K.to(points.dtype)
    u = K[0, 0] * camera[:, 0] / safe_z + K[0, 2]
    v = K[1, 1] * camera[:, 1] / safe_z + K[1, 2]
    pixel = torch.stack([u, v], dim=1).detach().floor().long()
    return pixel, z


def inside_image(pixel: Tensor, z: Tensor, width: int, height: int) -> Tensor:
    """[P] bool: in front of the camera (z > 0) and within a width x height image, for the
    (column, row) pixel indices [P, 2] of `project_points`."""
    return ((z > 0) & (pixel[:, 0] >= 0) & (pixel[:, 0] < width) & (pixel[:, 1] >= 0)
            & (pixel[:, 1] < height))


def depth_normals(depth: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:
    """Camera-space normals of the surface a depth map [H, W] describes.

    Each pixel's four neighbours are back-projected; the normal is the normalised cross product
    (P_right - P_left) x (P_down - P_up), oriented to face away from the camera (n . P > 0 at the
    pixel's point P, the convention of the rendered planar normals). Returns normals [H, W, 3]
    and valid [H, W] bool: interior pixels that, and whose four neighbours, have depth > 0, with
    a non-degenerate cross product. Computed on contiguous [H, W] planes of x, y and z (a cross
    product of strided [H, W, 3] slices, forward and backward, was 13 times slower on 640 x 512).
    """
    rays = pixel_rays(K, depth.shape[1], depth.shape[0], depth.dtype)
    x, y, z = depth * rays[:1, :, 0], depth * rays[:, :1, 1], depth  # [H, W] each

    def across(plane: Tensor) -> Tensor:  # right minus left neighbour, interior [H-2, W-2]
        return plane[1:-1, 2:] - plane[1:-1, :-2]

    def down(plane: Tensor) -> Tensor:  # lower minus upper neighbour, interior [H-2, W-2]
        return plane[2:, 1:-1] - plane[:-2, 1:-1]

    hx, hy, hz = across(x), across(y), across(z)
    vx, vy, vz = down(x), down(y), down(z)
    cross = (hy * vz - hz * vy, hz * vx - hx * vz, hx * vy - hy * vx)
    # clamped inside the sqrt: where nothing is rendered the cross product is 0, and the sqrt's
    # infinite slope there would make the gradient of any loss NaN, masked pixels included
    length = torch.sqrt((cross[0].square() + cross[1].square() + cross[2].square())
                        .clamp_min(1e-24))
    facing = cross[0] * x[1:-1, 1:-1] + cross[1] * y[1:-1, 1:-1] + cross[2] * z[1:-1, 1:-1]
    scale = torch.where(facing < 0, -1.0, 1.0) / length
    normals = torch.nn.functional.pad(torch.stack([c * scale for c in cross], dim=-1),
                                      (0, 0, 1, 1, 1, 1))
    positive = depth > 0
    valid = torch.zeros(depth.shape, dtype=torch.bool, device=depth.device)
    valid[1:-1, 1:-1] = (positive[1:-1, 2:] & positive[1:-1, :-2] & positive[2:, 1:-1]
                         & positive[:-2, 1:-1] & positive[1:-1, 1:-1] & (length > 1e-12))
    return normals, valid

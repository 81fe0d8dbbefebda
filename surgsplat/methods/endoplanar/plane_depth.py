"""Planar (flattened) Gaussians: per-Gaussian normal and plane distance, and the unbiased depth of
EndoPlanar Eq. 5-6 (after PGSR).

A flattened Gaussian is a small disc; its normal is the axis of its smallest scale, flipped to
face away from the camera (n . mean > 0). Alpha-blending the camera-space normals and plane
distances d = n . mean as two render channels gives a normal map N and a distance map D_perp;
the depth of pixel p is then the intersection of its ray r(p) = K^-1 [u, v, 1] with the blended
plane, D(p) = D_perp(p) / (N(p) . r(p)), unbiased by the Gaussians' extent along the ray.
"""

from __future__ import annotations

import torch
from torch import Tensor

from surgsplat.image.pinhole import pixel_ray_axes
from surgsplat.render.rotation import quaternion_to_matrix


def planar_normals_and_distances(means: Tensor, scales: Tensor, quats: Tensor,
                                 world_to_camera: Tensor) -> tuple[Tensor, Tensor]:
    """Camera-space normals [N, 3] (smallest-scale axis, facing away from the camera) and plane
    distances [N] (scene units) of Gaussians with world means [N, 3], scales [N, 3] and
    quaternions [N, 4] (w, x, y, z), seen by a camera world_to_camera [4, 4]."""
    axes = quaternion_to_matrix(torch.nn.functional.normalize(quats, dim=-1))  # [N, 3, 3]
    smallest = torch.argmin(scales, dim=1)
    world_normals = torch.gather(axes, 2, smallest[:, None, None].expand(-1, 3, 1)).squeeze(2)
    rotation = world_to_camera[:3, :3].to(means)
    normals = world_normals @ rotation.T  # [N, 3]: only the normal is rotated
    means_camera = means @ rotation.T + world_to_camera[:3, 3].to(means)
    distance = (normals * means_camera).sum(1)
    sign = torch.where(distance < 0, -1.0, 1.0).to(means)
    return normals * sign[:, None], distance * sign


def unbiased_plane_depth(normal_map: Tensor, distance_map: Tensor, K: Tensor) -> Tensor:
    """[H, W] depth D_perp / (N . r) (scene units) from a blended normal map [H, W, 3] and plane
    distance map [H, W]; 0 where the blended plane is parallel to the ray (|N . r| < 1e-6)."""
    height, width = distance_map.shape
    ray_x, ray_y = pixel_ray_axes(K, width, height, normal_map.dtype)
    denominator = (normal_map[..., 0] * ray_x + normal_map[..., 1] * ray_y[:, None]
                   + normal_map[..., 2])
    safe = denominator.abs() > 1e-6
    return torch.where(safe, distance_map / torch.where(safe, denominator,
                                                        torch.ones_like(denominator)),
                       torch.zeros_like(distance_map))

"""Quaternion helpers."""

import torch
from torch import Tensor


def quaternion_to_matrix(quats: Tensor) -> Tensor:
    """[..., 4] quaternions (w, x, y, z), normalised here -> [..., 3, 3] rotation matrices."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(*quats.shape[:-1], 3, 3)


def quaternion_third_axis(quats: Tensor) -> Tensor:
    """[..., 4] quaternions (w, x, y, z), normalised here -> [..., 3] the third column of
    `quaternion_to_matrix` (the rotated z axis), at a third of its cost."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    return torch.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], dim=-1)


def quaternion_multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product a b of quaternions [..., 4] (w, x, y, z): the rotation b, then a."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw], dim=-1)


def axis_angle_to_quaternion(rotvec: Tensor) -> Tensor:
    """[..., 3] rotation vectors (axis times angle, radians) -> [..., 4] unit quaternions
    (w, x, y, z); smooth at the zero rotation."""
    angle = rotvec.square().sum(-1, keepdim=True).add(1e-20).sqrt()  # [..., 1]
    half = 0.5 * angle
    # sin(half) / angle, by its series near 0 where the division loses precision.
    scale = torch.where(angle < 1e-4, 0.5 - angle.square() / 48.0,
                        torch.sin(half) / angle.clamp_min(1e-4))
    return torch.cat([torch.cos(half), rotvec * scale], dim=-1)

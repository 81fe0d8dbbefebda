"""Projection of 3D Gaussians to screen-space ellipses (EWA splatting): one contract, two backends.

`native`: the C++/OpenMP kernel in csrc/project (float32 Gaussians), forward and backward
written out per Gaussian, with the camera's gradients (world_to_camera's rotation block and
translation, K's fx, fy, cx, cy) summed over the Gaussians in a fixed order. `reference`: PyTorch
with autograd (any dtype). Both are differentiable in the Gaussians and the camera; `auto` picks
native for float32 CPU Gaussians when it is built.
At 100k Gaussians the reference's many small batched operations cost about as much as the
rasterizer itself on a 2-core CPU; the kernel takes a few milliseconds.

Pixel (column i, row j) has its centre at (i + 0.5, j + 0.5); K maps camera coordinates to these
continuous pixel coordinates. The camera looks down +z.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from surgsplat.render.native import Backend, dense_grad, native_module, resolve_backend
from surgsplat.render.rotation import quaternion_to_matrix

FOV_CLAMP = 1.3
"""Means outside 1.3x the field of view use the Jacobian at the clamped position (as 3DGS)."""


@dataclass
class Projection:
    """Screen-space Gaussians; entries with radii == 0 are culled and never rasterised."""

    means2d: Tensor  # [N, 2] pixel coordinates (x, y)
    conics: Tensor  # [N, 3] inverse 2D covariance (a, b, c): q = a dx^2 + 2 b dx dy + c dy^2
    depths: Tensor  # [N] camera-space z, scene units
    radii: Tensor  # [N] int32 3-sigma radius in pixels, 0 = culled
    means_camera: Tensor  # [N, 3] camera-space means
    rotations_camera: Tensor  # [N, 3, 3] Gaussian axes in camera space (columns)


def covariance_3d(scales: Tensor, quats: Tensor) -> tuple[Tensor, Tensor]:
    """[N,3] scales, [N,4] quaternions -> ([N,3,3] covariance R S S R^T, [N,3,3] R)."""
    rotation = quaternion_to_matrix(quats)
    axes = rotation * scales[:, None, :]
    return axes @ axes.transpose(1, 2), rotation


def project(means: Tensor, scales: Tensor, quats: Tensor, K: Tensor, width: int, height: int,
            world_to_camera: Tensor | None = None, near: float = 0.01, lowpass: float = 0.3,
            backend: Backend = "auto") -> Projection:
    """Project Gaussians (means [N,3], scales [N,3] linear, quats [N,4] (w,x,y,z)) with the pinhole
    K [3,3] and pose world_to_camera [4,4] (identity when None).

    The 2D covariance is J W Sigma W^T J^T + lowpass * I (EWA with a `lowpass` pixel dilation);
    Gaussians with depth below `near`, a degenerate covariance, or a 3-sigma box entirely outside
    the image get radius 0. Gradients reach the Gaussians, K (fx, fy, cx, cy) and
    world_to_camera (its rotation block and translation, as free entries: a pose correction
    keeps it rigid, see surgsplat.model.camera_refine).
    """
    if world_to_camera is None:
        world_to_camera = torch.eye(4, dtype=means.dtype)
    # The camera is read as float32 numbers, whatever its dtype: only the Gaussians decide.
    if resolve_backend("project", backend, [means, scales, quats]) == "native":
        return _native_project(means, scales, quats, K, width, height, world_to_camera, near,
                               lowpass)
    return project_reference(means, scales, quats, K, width, height, world_to_camera, near,
                             lowpass)


def project_reference(means: Tensor, scales: Tensor, quats: Tensor, K: Tensor, width: int,
                      height: int, world_to_camera: Tensor, near: float,
                      lowpass: float) -> Projection:
    """`project` in PyTorch with autograd."""
    dtype = means.dtype
    K = K.to(dtype)
    world_to_camera = world_to_camera.to(dtype)
    R_wc, t_wc = world_to_camera[:3, :3], world_to_camera[:3, 3]
    means_cam = means @ R_wc.T + t_wc
    x, y, z = means_cam.unbind(-1)
    in_front = z > near
    z_safe = torch.where(in_front, z, torch.full_like(z, near))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    tan_x = FOV_CLAMP * 0.5 * width / fx
    tan_y = FOV_CLAMP * 0.5 * height / fy
    x_clamped = torch.clamp(x / z_safe, -tan_x, tan_x) * z_safe
    y_clamped = torch.clamp(y / z_safe, -tan_y, tan_y) * z_safe
    zeros = torch.zeros_like(z)
    jacobian = torch.stack([
        fx / z_safe, zeros, -fx * x_clamped / z_safe**2,
        zeros, fy / z_safe, -fy * y_clamped / z_safe**2,
    ], dim=-1).reshape(-1, 2, 3)

    cov3d, rotation = covariance_3d(scales, quats)
    cov_cam = R_wc @ cov3d @ R_wc.T
    cov2d = jacobian @ cov_cam @ jacobian.transpose(1, 2)
    cov_xx = cov2d[:, 0, 0] + lowpass
    cov_xy = cov2d[:, 0, 1]
    cov_yy = cov2d[:, 1, 1] + lowpass
    det = cov_xx * cov_yy - cov_xy**2
    valid = in_front & (det > 0)
    det_safe = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([cov_yy / det_safe, -cov_xy / det_safe, cov_xx / det_safe], dim=-1)

    means2d = torch.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], dim=-1)
    with torch.no_grad():
        half_trace = 0.5 * (cov_xx + cov_yy)
        big_eigen = half_trace + torch.sqrt(torch.clamp(half_trace**2 - det, min=0.01))
        radii = torch.ceil(3.0 * torch.sqrt(big_eigen))
        on_screen = ((means2d[:, 0] + radii > 0) & (means2d[:, 0] - radii < width)
                     & (means2d[:, 1] + radii > 0) & (means2d[:, 1] - radii < height))
        radii = torch.where(valid & on_screen & torch.isfinite(radii), radii, 0.0)
        radii = radii.clamp(max=float(2 * max(width, height) + 1)).to(torch.int32)
    return Projection(means2d=means2d, conics=conics, depths=z, radii=radii,
                      means_camera=means_cam, rotations_camera=R_wc @ rotation)


class _NativeProject(torch.autograd.Function):
    """Autograd wrapper of the native projection kernels: gradients of the Gaussians and of the
    camera, world_to_camera [4, 4] and K [3, 3] (its fx, fy, cx, cy entries)."""

    @staticmethod
    def forward(ctx, means, scales, quats, world_to_camera, K, settings):
        native = native_module()
        inputs = [t.detach().contiguous() for t in (means, scales, quats)]
        fx, fy, cx, cy = (float(K[i, j]) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
        camera_args = (world_to_camera.detach().to(torch.float32).contiguous().numpy(),
                       fx, fy, cx, cy, *settings, FOV_CLAMP)
        n = means.shape[0]
        outputs = [torch.empty(n, 2), torch.empty(n, 3), torch.empty(n),
                   torch.empty(n, dtype=torch.int32), torch.empty(n, 3), torch.empty(n, 3, 3)]
        native.project_forward(*(t.numpy() for t in inputs), *camera_args,
                               *(t.numpy() for t in outputs))
        ctx.camera_args = camera_args
        ctx.camera_dtypes = (world_to_camera.dtype, K.dtype)
        ctx.save_for_backward(*inputs)
        ctx.mark_non_differentiable(outputs[3])
        return tuple(outputs)

    @staticmethod
    def backward(ctx, grad_means2d, grad_conics, grad_depths, _grad_radii, grad_means_camera,
                 grad_rotations_camera):
        native = native_module()
        means, scales, quats = ctx.saved_tensors
        n = means.shape[0]
        upstream = [dense_grad(grad_means2d, (n, 2)), dense_grad(grad_conics, (n, 3)),
                    dense_grad(grad_depths, (n,)), dense_grad(grad_means_camera, (n, 3)),
                    dense_grad(grad_rotations_camera, (n, 3, 3))]
        grads = [torch.empty_like(means), torch.empty_like(scales), torch.empty_like(quats)]
        grad_pose, grad_intrinsics = torch.empty(4, 4), torch.empty(4)
        native.project_backward(means.numpy(), scales.numpy(), quats.numpy(), *ctx.camera_args,
                                *(g.numpy() for g in upstream), *(g.numpy() for g in grads),
                                grad_pose.numpy(), grad_intrinsics.numpy())
        pose_dtype, K_dtype = ctx.camera_dtypes
        grad_K = None
        if ctx.needs_input_grad[4]:
            grad_K = torch.zeros(3, 3, dtype=K_dtype)
            grad_K[0, 0], grad_K[1, 1], grad_K[0, 2], grad_K[1, 2] = grad_intrinsics
        grad_pose = grad_pose.to(pose_dtype) if ctx.needs_input_grad[3] else None
        return (*grads, grad_pose, grad_K, None)


def _native_project(means: Tensor, scales: Tensor, quats: Tensor, K: Tensor, width: int,
                    height: int, world_to_camera: Tensor, near: float,
                    lowpass: float) -> Projection:
    means2d, conics, depths, radii, means_camera, rotations_camera = _NativeProject.apply(
        means, scales, quats, world_to_camera, K, (width, height, near, lowpass))
    return Projection(means2d=means2d, conics=conics, depths=depths, radii=radii,
                      means_camera=means_camera, rotations_camera=rotations_camera)

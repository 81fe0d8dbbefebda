"""Real spherical harmonics up to degree 3 for view-dependent colour (the 3DGS convention:
colour = sum_k c_k Y_k(d) + 0.5, clamped at 0).

`sh_colour` is what the renderer calls: the colour of every Gaussian seen from the camera, by the
native kernel (csrc/sh, forward and backward in one pass over the Gaussians) when it can run the
inputs, else by the PyTorch reference `eval_sh` at `view_directions`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from surgsplat.render.native import Backend, dense_grad, native_module, resolve_backend

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """[N, 3] unit directions -> [N, (degree+1)^2] basis values."""
    x, y, z = dirs.unbind(-1)
    basis = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        basis += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2 * zz - xx - yy),
                  SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        basis += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * xy * z,
                  SH_C3[2] * y * (4 * zz - xx - yy), SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
                  SH_C3[4] * x * (4 * zz - xx - yy), SH_C3[5] * z * (xx - yy),
                  SH_C3[6] * x * (xx - 3 * yy)]
    return torch.stack(basis, dim=-1)


def _check_degree(degree: int, coeffs: Tensor) -> int:
    """The number of coefficients degree uses, after checking coeffs [N, K, 3] has them."""
    if not 0 <= degree <= 3:
        raise ValueError(f"spherical-harmonic degree must be 0..3, got {degree}")
    num = (degree + 1) ** 2
    if coeffs.dim() != 3 or coeffs.shape[1] < num or coeffs.shape[2] != 3:
        raise ValueError(f"degree {degree} needs SH coefficients [N, K >= {num}, 3], got "
                         f"{tuple(coeffs.shape)}")
    return num


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Colour [N, 3] of SH coefficients [N, K>=(degree+1)^2, 3] seen along unit dirs [N, 3]."""
    num = _check_degree(degree, coeffs)
    basis = sh_basis(degree, dirs)  # [N, num]
    return torch.clamp_min((basis[:, :, None] * coeffs[:, :num]).sum(1) + 0.5, 0.0)


def camera_centre(world_to_camera: Tensor | None, dtype: torch.dtype) -> Tensor:
    """[3] the camera's centre in the world frame (the origin when world_to_camera is None)."""
    w2c = torch.eye(4, dtype=dtype) if world_to_camera is None else world_to_camera.to(dtype)
    return -w2c[:3, :3].T @ w2c[:3, 3]


def view_directions(means: Tensor, world_to_camera: Tensor | None = None) -> Tensor:
    """[N, 3] unit directions from the camera centre to the means [N, 3] (world frame), the
    directions at which spherical-harmonic colour is evaluated."""
    return torch.nn.functional.normalize(means - camera_centre(world_to_camera, means.dtype),
                                         dim=-1)


def sh_colour(degree: int, coeffs: Tensor, means: Tensor, world_to_camera: Tensor | None = None,
              backend: Backend = "auto") -> Tensor:
    """Colour [N, 3] of the SH coefficients [N, K >= (degree+1)^2, 3] of Gaussians at means
    [N, 3], seen from the camera world_to_camera [4, 4] (None: at the origin):
    eval_sh(degree, coeffs, view_directions(means, world_to_camera)).

    backend "native": the fused kernel (float32 CPU tensors); "reference": PyTorch; "auto":
    native when it can run the inputs. Both are differentiable in the coefficients, the means
    and the camera (through its centre).
    """
    _check_degree(degree, coeffs)
    if resolve_backend("sh", backend, [coeffs, means]) == "native":
        centre = camera_centre(world_to_camera, torch.float32)
        return _NativeSh.apply(coeffs, means, centre, degree)
    return eval_sh(degree, coeffs, view_directions(means, world_to_camera))


class _NativeSh(torch.autograd.Function):
    """Autograd wrapper of the native kernels; the degree is a constant. The colour depends on
    a mean and the camera centre [3] through their difference only, so the centre's gradient is
    minus the sum of the means' (the direction's part of them)."""

    @staticmethod
    def forward(ctx, coeffs: Tensor, means: Tensor, centre: Tensor, degree: int) -> Tensor:
        inputs = [x.detach().contiguous() for x in (coeffs, means, centre)]
        rgb = means.new_empty(means.shape[0], 3)
        native_module().sh_forward(*(x.numpy() for x in inputs), degree, rgb.numpy())
        ctx.save_for_backward(*inputs)
        ctx.degree = degree
        return rgb

    @staticmethod
    def backward(ctx, grad_rgb: Tensor) -> tuple[Tensor, Tensor, Tensor | None, None]:
        coeffs, means, centre = ctx.saved_tensors
        grad_coeffs, grad_means = torch.empty_like(coeffs), torch.empty_like(means)
        native_module().sh_backward(coeffs.numpy(), means.numpy(), centre.numpy(), ctx.degree,
                                    dense_grad(grad_rgb, (means.shape[0], 3)).numpy(),
                                    grad_coeffs.numpy(), grad_means.numpy())
        grad_centre = -grad_means.sum(dim=0) if ctx.needs_input_grad[2] else None
        return grad_coeffs, grad_means, grad_centre, None

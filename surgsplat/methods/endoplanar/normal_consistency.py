"""EndoPlanar's normal consistency (Eq. 7-8): how far a rendered normal map is from the normals
of the surface a rendered depth map describes.

Per pixel p, the L1 distance |n_depth(p) - normalize(N(p))|_1 between the depth map's normal
(`pinhole.depth_normals`: the cross product of the four back-projected neighbours, facing away
from the camera) and the rendered normal N(p), times a weight w(p). It is summed over the counted
pixels: those of a mask whose depth normal is valid (interior pixels whose own and four
neighbours' depths are > 0, with a non-degenerate cross product).

Two implementations with one contract: the fused native kernels of this package's csrc/
(float32 CPU maps; one pass forward, two backward, where the PyTorch ops take some forty passes
over the image) and `normal_consistency_reference`, composed of PyTorch ops and differentiated by
autograd (any dtype, and the only one that gives K a gradient).
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from surgsplat.image.pinhole import depth_normals, pixel_ray_axes
from surgsplat.render.native import Backend, dense_grad, native_module, resolve_backend


def normal_consistency_reference(depth: Tensor, normals: Tensor, K: Tensor, mask: Tensor,
                                 weights: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """`normal_consistency` in PyTorch ops, with autograd."""
    from_depth, valid = depth_normals(depth, K)
    rendered = torch.nn.functional.normalize(normals, dim=-1)
    counted = valid & mask
    error = (from_depth - rendered).abs().sum(-1)
    if weights is not None:
        error = error * weights
    return (error * counted).sum(), counted.sum()


class _NativeNormalConsistency(torch.autograd.Function):
    """(sum, count) of the native kernels, with the backward of the sum."""

    @staticmethod
    def forward(ctx, depth, normals, ray_x, ray_y, mask, weights):
        depth, normals = depth.detach().contiguous(), normals.detach().contiguous()
        total, count = native_module().normal_consistency_forward(
            depth.numpy(), normals.numpy(), ray_x.numpy(), ray_y.numpy(), mask.numpy(),
            None if weights is None else weights.numpy())
        ctx.save_for_backward(depth, normals, ray_x, ray_y, mask, weights)
        count = torch.tensor(count)
        ctx.mark_non_differentiable(count)
        return torch.tensor(total, dtype=depth.dtype), count

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_sum, _grad_count):
        depth, normals, ray_x, ray_y, mask, weights = ctx.saved_tensors
        grad_depth, grad_normals = (torch.empty_like(value) if needed else None for value, needed
                                    in zip((depth, normals), ctx.needs_input_grad[:2]))
        native_module().normal_consistency_backward(
            depth.numpy(), normals.numpy(), ray_x.numpy(), ray_y.numpy(), mask.numpy(),
            None if weights is None else weights.numpy(), float(dense_grad(grad_sum, ())),
            None if grad_depth is None else grad_depth.numpy(),
            None if grad_normals is None else grad_normals.numpy())
        return grad_depth, grad_normals, None, None, None, None


def normal_consistency(depth: Tensor, normals: Tensor, K: Tensor, mask: Tensor,
                       weights: Tensor | None = None,
                       backend: Backend = "auto") -> tuple[Tensor, Tensor]:
    """(sum, count): the sum over the counted pixels of w(p) |n_depth(p) - normalize(N(p))|_1
    (differentiable in depth and normals), and how many pixels were counted (an integer tensor).

    depth [H, W] (scene units), normals [H, W, 3] (any length), K [3, 3] pinhole intrinsics,
    mask bool [H, W] (the pixels that may count), weights [H, W] or None (ones). The native
    kernels run float32 CPU maps unless K needs a gradient; else the reference.
    """
    height, width = depth.shape
    if normals.shape != (height, width, 3):
        raise ValueError(f"normals: expected shape {(height, width, 3)}, got "
                         f"{tuple(normals.shape)}")
    if mask.shape != (height, width) or mask.dtype != torch.bool:
        raise ValueError(f"mask: expected bool {(height, width)}, got {mask.dtype} "
                         f"{tuple(mask.shape)}")
    if weights is not None and weights.shape != (height, width):
        raise ValueError(f"weights: expected shape {(height, width)}, got "
                         f"{tuple(weights.shape)}")
    maps = [depth, normals] + ([] if weights is None else [weights])
    if K.requires_grad or resolve_backend("normal_consistency", backend, maps) == "reference":
        if backend == "native":
            raise ValueError("normal_consistency: the native backend gives K no gradient")
        return normal_consistency_reference(depth, normals, K, mask, weights)
    ray_x, ray_y = pixel_ray_axes(K.detach(), width, height)
    return _NativeNormalConsistency.apply(
        depth, normals, ray_x, ray_y, mask.contiguous(),
        None if weights is None else weights.detach().contiguous())

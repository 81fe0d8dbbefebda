"""Pure-PyTorch rasterizer: the obviously-correct reference with the native kernel's contract.

Dense over (Gaussian, pixel) pairs, so only for small scenes: tests, gradcheck, and as the
fallback when the native module is missing. Autograd provides every gradient.

Compositing rule (shared with csrc/rasterize): Gaussians in increasing depth; for pixel p,
alpha_i = min(0.99, o_i exp(-q_i / 2)), skipped when below 1/255; transmittance T_i is the
product of (1 - alpha_j) over the earlier non-skipped Gaussians; Gaussian i contributes
alpha_i T_i f_i if T_i (1 - alpha_i) >= 1e-4, and compositing stops at the first one that does not.
"""

from __future__ import annotations

import torch
from torch import Tensor

from surgsplat.render.pixel_weights import PixelWeights

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
TRANSMITTANCE_MIN = 1e-4


def pixel_centres(width: int, height: int, dtype: torch.dtype) -> Tensor:
    """[H*W, 2] pixel-centre coordinates (x, y), row-major."""
    y, x = torch.meshgrid(torch.arange(height, dtype=dtype) + 0.5,
                          torch.arange(width, dtype=dtype) + 0.5, indexing="ij")
    return torch.stack([x.reshape(-1), y.reshape(-1)], dim=-1)


def rasterize_reference(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor,
                        depths: Tensor, radii: Tensor, width: int, height: int,
                        absgrad: Tensor | None = None, background: Tensor | None = None,
                        gradient_weights: PixelWeights | None = None) -> tuple[Tensor, Tensor]:
    """Composite Gaussians front to back -> (image [H,W,C], alpha [H,W]).

    means2d [N,2], conics [N,3], opacities [N], features [N,C], depths [N], radii [N] (0 = culled).
    absgrad [N], when given, gets sum over pixels of |d loss / d means2d| (per pixel, then the
    norm of the 2-vector) added during backward, the densification signal.
    background [C], when given, is added behind the Gaussians: image + (1 - alpha) background
    (data, as in the native kernel: it gets no gradient).
    gradient_weights: at pixel p, a member's alpha and features enter as x.detach() + w_p (x -
    x.detach()): their value, with w_p times their gradient (pixel_weights.PixelWeights).
    """
    image, alpha = _composite(means2d, conics, opacities, features, depths, radii, width, height,
                              absgrad, gradient_weights)
    if background is not None:
        image = image + (1.0 - alpha)[..., None] * background.detach().to(image)
    return image, alpha


def _composite(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor,
               depths: Tensor, radii: Tensor, width: int, height: int,
               absgrad: Tensor | None, gradient_weights: PixelWeights | None
               ) -> tuple[Tensor, Tensor]:
    """rasterize_reference without a background."""
    channels = features.shape[1]
    keep = torch.nonzero(radii > 0).squeeze(1)
    keep = keep[torch.argsort(depths[keep], stable=True)]
    if keep.numel() == 0:
        image = features.sum() * 0 + torch.zeros(height, width, channels, dtype=features.dtype)
        return image, torch.zeros(height, width, dtype=features.dtype)
    pixels = pixel_centres(width, height, means2d.dtype)  # [P, 2]
    offsets = pixels[None, :, :] - means2d[keep][:, None, :]  # [M, P, 2]
    if absgrad is not None and offsets.requires_grad:
        def accumulate(grad: Tensor) -> None:
            absgrad.index_add_(0, keep, grad.abs().sum(1).norm(dim=-1).to(absgrad.dtype))
        offsets.register_hook(accumulate)
    dx, dy = offsets.unbind(-1)
    a, b, c = conics[keep].unbind(-1)
    q = a[:, None] * dx**2 + 2 * b[:, None] * dx * dy + c[:, None] * dy**2
    alpha = torch.clamp(opacities[keep][:, None] * torch.exp(-0.5 * q), max=ALPHA_MAX)
    alpha = torch.where((alpha >= ALPHA_MIN) & (q >= 0), alpha, torch.zeros_like(alpha))
    scale = None  # [M, P] the weight of each (Gaussian, pixel) pair's gradient
    if gradient_weights is not None:
        members = gradient_weights.members[keep][:, None]
        scale = torch.where(members, gradient_weights.weights.reshape(1, -1).to(alpha), 1.0)
        alpha = alpha.detach() + scale * (alpha - alpha.detach())
    after = torch.cumprod(1 - alpha, dim=0)  # [M, P] transmittance after each Gaussian
    before = torch.cat([torch.ones_like(after[:1]), after[:-1]], dim=0)
    contributes = (after >= TRANSMITTANCE_MIN).to(alpha.dtype)
    weights = alpha * before * contributes  # [M, P]
    if scale is None:
        image = weights.T @ features[keep]  # [P, C]
    else:
        image = ((weights * scale).T @ features[keep]
                 + (weights * (1.0 - scale)).T @ features[keep].detach())
    alpha_total = weights.sum(0)
    return image.reshape(height, width, channels), alpha_total.reshape(height, width)

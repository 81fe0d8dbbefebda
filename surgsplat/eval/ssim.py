"""Structural similarity (SSIM, Wang et al. 2004), differentiable, for metrics and the D-SSIM loss.

Constants as in the paper: an 11x11 Gaussian window with sigma 1.5, C1 = (0.01 L)^2 and
C2 = (0.03 L)^2 with dynamic range L = 1 (images in [0, 1]). Each channel is filtered on its own
with a separable convolution. The SSIM map has the input's size ('same'): before filtering, each
image is padded by 5 pixels with mirror reflection about the edge pixel (torch's 'reflect', SciPy's
'mirror' mode: ``c b | a b c``), so border pixels see real image statistics rather than zeros.
The SSIM score is the mean of the map over all pixels and channels, or over the masked pixels.

Computed in the inputs' dtype: float32 (training) agrees with a float64 reference to about 1e-4
per pixel, as the variances E[x^2] - E[x]^2 lose digits; the metrics in `image_metrics` pass
float64 images.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

WINDOW_SIZE = 11
SIGMA = 1.5
C1 = 0.01 ** 2
C2 = 0.03 ** 2


def _gaussian_taps(dtype: torch.dtype, device: torch.device) -> Tensor:
    """[11] normalised 1D Gaussian window."""
    offsets = torch.arange(WINDOW_SIZE, dtype=dtype, device=device) - WINDOW_SIZE // 2
    taps = torch.exp(-offsets ** 2 / (2 * SIGMA ** 2))
    return taps / taps.sum()


def _blur(planes: Tensor) -> Tensor:
    """[1, P, H, W] -> [1, P, H, W]: separable Gaussian filter of each plane, mirror padding.

    The planes are the channels of one depthwise (grouped) convolution, which PyTorch runs far
    faster on CPU than a batch of single-channel convolutions.
    """
    count = planes.shape[1]
    taps = _gaussian_taps(planes.dtype, planes.device).expand(count, WINDOW_SIZE)  # [P, 11]
    radius = WINDOW_SIZE // 2
    padded = F.pad(planes, (radius, radius, radius, radius), mode="reflect")
    rows = F.conv2d(padded, taps.reshape(count, 1, 1, WINDOW_SIZE), groups=count)
    return F.conv2d(rows, taps.reshape(count, 1, WINDOW_SIZE, 1), groups=count)


def ssim_map(pred: Tensor, gt: Tensor) -> Tensor:
    """[H, W, C] per-pixel, per-channel SSIM of two images [H, W, C] in [0, 1].

    Differentiable with respect to both inputs. Needs H, W >= 6 (the mirror padding is 5 pixels).
    """
    if pred.shape != gt.shape or pred.dim() != 3:
        raise ValueError(f"expected two images of one shape [H, W, C], got {tuple(pred.shape)} "
                         f"and {tuple(gt.shape)}")
    if min(pred.shape[0], pred.shape[1]) <= WINDOW_SIZE // 2:
        raise ValueError(f"images of {pred.shape[0]}x{pred.shape[1]} pixels are too small for "
                         f"an {WINDOW_SIZE}x{WINDOW_SIZE} SSIM window")
    channels = pred.shape[2]
    x = pred.permute(2, 0, 1).unsqueeze(0)  # [1, C, H, W]
    y = gt.permute(2, 0, 1).unsqueeze(0)
    moments = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1))  # [1, 5C, H, W]
    mu_x, mu_y, xx, yy, xy = moments.split(channels, dim=1)
    var_x = xx - mu_x * mu_x
    var_y = yy - mu_y * mu_y
    cov = xy - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + C1) * (2 * cov + C2)
    denominator = (mu_x * mu_x + mu_y * mu_y + C1) * (var_x + var_y + C2)
    return (numerator / denominator)[0].permute(1, 2, 0)  # [H, W, C]


def ssim(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Tensor:
    """Scalar SSIM of two images [H, W, C] in [0, 1].

    Without a mask: the mean of `ssim_map` over all pixels and channels. With a mask (bool [H, W],
    True = count the pixel): the mean of the map over the masked pixels and all channels; the
    images themselves are not altered, so windows centred on counted pixels still see their
    uncounted neighbours. Differentiable; `1 - ssim(...)` is the D-SSIM loss.
    """
    values = ssim_map(pred, gt)  # [H, W, C]
    if mask is None:
        return values.mean()
    if mask.shape != values.shape[:2] or mask.dtype != torch.bool:
        raise ValueError(f"expected a bool mask of shape {tuple(values.shape[:2])}, got "
                         f"{mask.dtype} {tuple(mask.shape)}")
    if not mask.any():
        raise ValueError("the SSIM mask selects no pixel")
    return values[mask].mean()

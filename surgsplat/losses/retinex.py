"""LumiState's Retinex losses (`lumistate.txt` Section 2.2, Eq. 7-8), over tissue pixels.

- `retinex_loss` (Eq. 7): the L1 distance between the product R_t * L_t of the rendered
  reflectance [H, W, 3] and the illumination map [H, W] and the observed image, so that the two
  factors explain the frame;
- `bright_channel_loss` (Eq. 8): the mean squared distance of L_t from the bright channel
  B_t = MaxPool_{2 r0 + 1}(max(R, G, B)) of the observed image, which anchors the illumination
  to the local peak brightness (an upper bound of it when the reflectance is at most 1) and
  keeps it from collapsing.
Both are zero for an exact factorisation I = R * L whose L is the bright channel of I.
"""

from __future__ import annotations

from torch import Tensor

from surgsplat.fields.illumination import bright_channel, brightness
from surgsplat.losses.photometric import masked_l1


def retinex_loss(reflectance: Tensor, illumination: Tensor, image: Tensor, tissue: Tensor) -> Tensor:
    """Eq. 7: mean |R * L - I| over the tissue pixels [H, W] (bool) and the 3 channels, for
    R [H, W, 3], L [H, W] and I [H, W, 3]."""
    return masked_l1(reflectance * illumination[..., None], image, tissue)


def bright_channel_loss(illumination: Tensor, image: Tensor, tissue: Tensor,
                        radius: int) -> Tensor:
    """Eq. 8: mean (L - B)^2 over the tissue pixels [H, W] (bool), for L [H, W] and the bright
    channel B of the image [H, W, 3] with windows of 2 radius + 1 pixels; 0 without tissue."""
    target = bright_channel(brightness(image), radius)  # [H, W]
    weights = tissue.to(illumination.dtype)
    return ((illumination - target) ** 2 * weights).sum() / weights.sum().clamp_min(1.0)

"""LumiState's Retinex losses (`lumistate.txt` Section 2.2, Eq. 7-8), over tissue pixels.

- `retinex_loss` (Eq. 7): the L1 distance between the product R_t * L_t of the rendered
  reflectance [H, W, 3] and the illumination map [H, W] and the observed image, so that the two
  factors explain the frame;
- `bright_channel_loss` (Eq. 8): the mean squared distance of L_t from the bright channel
  B_t = MaxPool_{2 r0 + 1}(max(R, G, B)) of the observed image, which anchors the illumination
  to the local peak brightness (an upper bound of it when the reflectance is at most 1) and
  keeps it from collapsing;
- `illumination_transfer_loss` (a deviation from the paper, see the lumistate preset): the L1
  distance between the rendered gain G_t (each Gaussian's modulated colour over its reflectance
  colour, alpha-blended) and L_t, so that the modulation carries the illumination map and the
  photometric loss pulls the reflectance to I / L_t, as Eq. 7 does.
All three are zero for an exact factorisation I = R * L whose L is the bright channel of I and
whose modulation multiplies each Gaussian's colour by L.
"""

from __future__ import annotations

from torch import Tensor

from surgsplat.methods.lumistate.illumination import bright_channel, brightness
from surgsplat.losses.photometric import masked_l1


def retinex_loss(reflectance: Tensor, illumination: Tensor, image: Tensor,
                 tissue: Tensor) -> Tensor:
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


def illumination_transfer_loss(gain: Tensor, illumination: Tensor, alpha: Tensor,
                               tissue: Tensor) -> Tensor:
    """mean |G - alpha L| over the tissue pixels [H, W] (bool), for the rendered gain G
    [H, W, 1] (alpha-blended, so compared with L [H, W] times the accumulated opacity alpha
    [H, W]); L and alpha are targets here (no gradient through them: letting L follow G too
    left the reflectance error unchanged or worse, measured in docs/methods/lumistate.md,
    Deviations)."""
    target = (illumination * alpha).detach()[..., None]  # [H, W, 1]
    return masked_l1(gain, target, tissue)

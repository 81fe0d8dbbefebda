"""LumiState's illumination estimation network (`lumistate.txt` Section 2.1, Eq. 2-3).

The network sees only the brightness projection S_t = max(R, G, B) of a frame (Eq. 2), which
keeps the spatial structure of the light and drops most of the reflectance's colour, and
returns the illumination map L_t = sigmoid(U(S_t)) in [0, 1] (Eq. 3) and a compact embedding
e_t of its bottleneck, the frame's global illumination state.

Sized for a CPU: it runs on a downsampled brightness map (illumination is smooth), two 2x
poolings, `channels` feature maps at the first level doubling per level. The embedding is the
bottleneck averaged over a 2 x 2 grid (so it keeps where the light is: top, bottom, left,
right) and projected linearly to `embedding_dim` numbers.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

EMBEDDING_GRID = 2
"""The bottleneck is averaged over an EMBEDDING_GRID x EMBEDDING_GRID grid of cells."""
LEVELS = 3
"""Resolution levels of the UNet (two poolings): input sides must be multiples of 4."""


def brightness(image: Tensor) -> Tensor:
    """Eq. 2: [..., H, W, 3] RGB -> [..., H, W] per-pixel maximum channel S_t."""
    return image.max(dim=-1).values


def bright_channel(brightness_map: Tensor, radius: int) -> Tensor:
    """Eq. 8's B_t: [H, W] brightness -> [H, W] its maximum over (2 radius + 1)^2 windows (cut
    at the borders): the windows' maximum along rows, then along columns, each as the running
    maximum of 2 radius + 1 shifted views (F.max_pool2d gives the same values, 16 times slower
    on a CPU at 640 x 512)."""
    return _window_max(_window_max(brightness_map, radius, dim=1), radius, dim=0)


def _window_max(values: Tensor, radius: int, dim: int) -> Tensor:
    """[H, W] -> [H, W]: the maximum over the 2 radius + 1 entries centred on each along `dim`."""
    length = values.shape[dim]
    padding = (radius, radius, 0, 0) if dim == 1 else (0, 0, radius, radius)
    padded = F.pad(values[None], padding, value=float("-inf"))[0]
    result = padded.narrow(dim, 0, length)
    for shift in range(1, 2 * radius + 1):
        result = torch.maximum(result, padded.narrow(dim, shift, length))
    return result


def _block(inputs: int, outputs: int) -> nn.Sequential:
    """Two 3x3 convolutions with ReLU, keeping the resolution."""
    return nn.Sequential(nn.Conv2d(inputs, outputs, 3, padding=1), nn.ReLU(inplace=True),
                         nn.Conv2d(outputs, outputs, 3, padding=1), nn.ReLU(inplace=True))


class IlluminationUNet(nn.Module):
    """S_t [B, h, w] -> (L_t [B, h, w] in [0, 1], e_t [B, embedding_dim]); `encode` and
    `decode` split the two halves so that the embedding can be used without the map."""

    def __init__(self, channels: int = 8, embedding_dim: int = 16):
        super().__init__()
        widths = [channels * 2 ** level for level in range(LEVELS)]  # e.g. 8, 16, 32
        self.down = nn.ModuleList([_block(1, widths[0])] + [
            _block(widths[level - 1], widths[level]) for level in range(1, LEVELS)])
        self.up = nn.ModuleList([_block(widths[level] + widths[level - 1], widths[level - 1])
                                 for level in range(LEVELS - 1, 0, -1)])
        self.head = nn.Conv2d(widths[0], 1, 1)
        self.embed = nn.Linear(widths[-1] * EMBEDDING_GRID ** 2, embedding_dim)

    def encode(self, brightness_maps: Tensor) -> tuple[list[Tensor], Tensor]:
        """(features of every level, bottleneck last; e_t [B, embedding_dim]) of S_t [B, h, w]."""
        height, width = brightness_maps.shape[-2:]
        if height % 2 ** (LEVELS - 1) or width % 2 ** (LEVELS - 1):
            raise ValueError(f"brightness maps must have sides that are multiples of "
                             f"{2 ** (LEVELS - 1)}, got {height}x{width}")
        features = []
        x = brightness_maps[:, None]  # [B, 1, h, w]
        for level, block in enumerate(self.down):
            if level:
                x = F.max_pool2d(x, 2)
            x = block(x)
            features.append(x)
        pooled = F.adaptive_avg_pool2d(x, EMBEDDING_GRID).flatten(1)  # [B, C * grid^2]
        return features, self.embed(pooled)

    def decode(self, features: list[Tensor]) -> Tensor:
        """L_t [B, h, w] in [0, 1] (Eq. 3) from the features `encode` returned."""
        x = features[-1]
        for block, skip in zip(self.up, reversed(features[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return torch.sigmoid(self.head(x))[:, 0]

    def forward(self, brightness_maps: Tensor) -> tuple[Tensor, Tensor]:
        features, embedding = self.encode(brightness_maps)
        return self.decode(features), embedding

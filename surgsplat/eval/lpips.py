"""LPIPS perceptual distance (Zhang et al. 2018), version 0.1, AlexNet variant.

The distance between two images: both go through an AlexNet feature extractor (ImageNet
weights); at each of the five ReLU outputs the features are normalised to unit length over
channels, their squared difference is weighted per channel by a learnt 1x1 linear layer (no bias),
averaged over the layer's pixels, and the five layer values are summed.

Inputs are RGB images in [0, 1]; the model maps them to [-1, 1] (x * 2 - 1) and then applies the
LPIPS scaling layer ((x - shift) / scale) before AlexNet.

Weights:
- the linear layers ship with surgsplat (`weights/lpips_alex_v0.1.pth`, from the BSD-2-Clause
  `lpips` package; see `weights/LICENSE-lpips.txt`);
- the AlexNet backbone is torchvision's ImageNet checkpoint `alexnet-owt-7be5be79.pth`, which
  surgsplat does not ship. It is read from, in order: the path given to `load_lpips`, the
  `SURGSPLAT_ALEXNET_WEIGHTS` environment variable, torch's hub cache (`torch.hub.get_dir()` /
  checkpoints: `$TORCH_HOME/hub/checkpoints/`, by default `~/.cache/torch/hub/checkpoints/`).

Tool pixels (project convention, as in the common EndoNeRF-style evaluation code):
`lpips_distance` with a tissue mask sets tool pixels to 0 (black) in both images before the
network, and averages over the whole image.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from surgsplat.errors import DataError
from surgsplat.train.checkpoint import read_torch_file

ALEXNET_FILENAME = "alexnet-owt-7be5be79.pth"
ALEXNET_ENV = "SURGSPLAT_ALEXNET_WEIGHTS"
LINEAR_WEIGHTS = Path(__file__).resolve().parent / "weights" / "lpips_alex_v0.1.pth"
MIN_SIZE = 31  # smallest height / width that survives AlexNet's strides and pools

# (torchvision key prefix, in channels, out channels, kernel, stride, padding) of conv1..conv5
_ALEXNET_CONVS = (
    ("features.0", 3, 64, 11, 4, 2),
    ("features.3", 64, 192, 5, 1, 2),
    ("features.6", 192, 384, 3, 1, 1),
    ("features.8", 384, 256, 3, 1, 1),
    ("features.10", 256, 256, 3, 1, 1),
)


class AlexNetFeatures(nn.Module):
    """AlexNet's convolutional trunk; returns the five post-ReLU feature maps of conv1..conv5."""

    def __init__(self) -> None:
        super().__init__()
        self.convs = nn.ModuleList(
            nn.Conv2d(cin, cout, kernel, stride=stride, padding=padding)
            for _, cin, cout, kernel, stride, padding in _ALEXNET_CONVS)

    def forward(self, x: Tensor) -> list[Tensor]:
        """[B, 3, H, W] -> five maps [B, 64|192|384|256|256, h_i, w_i]."""
        features = []
        for index, conv in enumerate(self.convs):
            if index in (1, 2):  # max-pool after conv1's and conv2's ReLU
                x = F.max_pool2d(x, kernel_size=3, stride=2)
            x = F.relu(conv(x))
            features.append(x)
        return features


class LPIPS(nn.Module):
    """LPIPS v0.1 (AlexNet). Forward: two [B, 3, H, W] batches in [0, 1] -> [B] distances."""

    def __init__(self) -> None:
        super().__init__()
        self.backbone = AlexNetFeatures()
        self.lins = nn.ModuleList(
            nn.Conv2d(spec[2], 1, kernel_size=1, bias=False) for spec in _ALEXNET_CONVS)
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))

    def forward(self, pred: Tensor, gt: Tensor) -> Tensor:
        if pred.shape != gt.shape or pred.dim() != 4 or pred.shape[1] != 3:
            raise ValueError(f"expected two batches of one shape [B, 3, H, W], got "
                             f"{tuple(pred.shape)} and {tuple(gt.shape)}")
        if min(pred.shape[2:]) < MIN_SIZE:
            raise ValueError(f"LPIPS needs images of at least {MIN_SIZE}x{MIN_SIZE} pixels, got "
                             f"{pred.shape[2]}x{pred.shape[3]}")
        both = torch.cat([pred, gt]) * 2 - 1  # [2B, 3, H, W] in [-1, 1]
        features = self.backbone((both - self.shift) / self.scale)
        distance = pred.new_zeros(pred.shape[0])
        for feature, lin in zip(features, self.lins):
            unit = feature / (feature.norm(dim=1, keepdim=True) + 1e-10)  # [2B, C, h, w]
            unit_pred, unit_gt = unit.chunk(2)
            distance = distance + lin((unit_pred - unit_gt) ** 2).mean(dim=(1, 2, 3))
        return distance


def _backbone_path(explicit: Path | None) -> tuple[Path | None, str | None]:
    """The AlexNet checkpoint to read, or None and the places searched."""
    if explicit is not None:
        if not Path(explicit).is_file():
            raise DataError(explicit, "AlexNet weights not found")
        return Path(explicit), None
    from_env = os.environ.get(ALEXNET_ENV)
    if from_env:
        if not Path(from_env).is_file():
            raise DataError(from_env, f"AlexNet weights named by ${ALEXNET_ENV} not found")
        return Path(from_env), None
    cached = Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_FILENAME
    if cached.is_file():
        return cached, None
    return None, (f"AlexNet ImageNet weights ({ALEXNET_FILENAME}) not found: looked in {cached}; "
                  f"set ${ALEXNET_ENV} to the file to enable LPIPS")


def _read_weights(path: Path, expected: str) -> dict[str, Tensor]:
    """The dictionary of tensors of the weights file `path`; DataError naming the file and
    `expected` (what it should hold) when it is not one."""
    state = read_torch_file(path, expected)
    if not isinstance(state, dict):
        raise DataError(path, f"expected {expected}, a dictionary of tensors")
    return state


def _take(state: dict[str, Tensor], key: str, shape: tuple[int, ...], path: Path) -> Tensor:
    tensor = state.get(key)
    if not isinstance(tensor, Tensor) or tuple(tensor.shape) != shape:
        found = "missing" if tensor is None else f"shape {tuple(getattr(tensor, 'shape', ()))}"
        raise DataError(path, f"expected tensor {key!r} of shape {shape}, {found}")
    return tensor.float()


def load_lpips(backbone_path: Path | None = None) -> tuple[LPIPS | None, str | None]:
    """The LPIPS model with its weights, in eval mode and frozen, or (None, why it is missing).

    Exactly one of the two is None. A missing AlexNet checkpoint in the default places gives a
    reason; a path given explicitly (argument or environment variable) that does not exist, or
    any weights file that cannot be read or lacks the expected tensors, raises `DataError`.
    """
    path, reason = _backbone_path(backbone_path)
    if path is None:
        return None, reason
    model = LPIPS()
    backbone = _read_weights(path, f"torchvision's AlexNet ImageNet weights ({ALEXNET_FILENAME})")
    with torch.no_grad():
        for conv, (prefix, cin, cout, kernel, _, _) in zip(model.backbone.convs, _ALEXNET_CONVS):
            shape = (cout, cin, kernel, kernel)
            conv.weight.copy_(_take(backbone, f"{prefix}.weight", shape, path))
            conv.bias.copy_(_take(backbone, f"{prefix}.bias", (cout,), path))
        linear = _read_weights(LINEAR_WEIGHTS, "the LPIPS v0.1 linear layers")
        for index, (lin, spec) in enumerate(zip(model.lins, _ALEXNET_CONVS)):
            lin.weight.copy_(_take(linear, f"lin{index}", (1, spec[2], 1, 1), LINEAR_WEIGHTS))
    return model.eval().requires_grad_(False), None


def lpips_distance(model: LPIPS, pred: Tensor, gt: Tensor, tissue: Tensor | None = None) -> float:
    """LPIPS between two images [H, W, 3] in [0, 1]; with a bool tissue mask [H, W] (True =
    tissue), tool pixels are set to 0 in both images first (the "zeroed" convention)."""
    if tissue is not None:
        if tissue.shape != pred.shape[:2] or tissue.dtype != torch.bool:
            raise ValueError(f"expected a bool tissue mask of shape {tuple(pred.shape[:2])}, "
                             f"got {tissue.dtype} {tuple(tissue.shape)}")
        keep = tissue.unsqueeze(-1).to(pred.dtype)  # [H, W, 1]
        pred, gt = pred * keep, gt * keep
    with torch.no_grad():
        return model(pred.permute(2, 0, 1)[None].float(), gt.permute(2, 0, 1)[None].float()).item()

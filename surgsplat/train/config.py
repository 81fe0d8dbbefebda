"""Optimisation settings of a training run."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal


@dataclass
class LearningRates:
    """Adam learning rates of the per-Gaussian parameters."""

    means: float = 1.6e-4
    """Initial rate of the means, times the scene extent (3DGS convention)."""
    means_final: float = 1.6e-6
    """Final rate of the means (exponential decay over the run), times the scene extent."""
    log_scales: float = 5e-3
    """Rate of the log-scales."""
    quats: float = 1e-3
    """Rate of the rotation quaternions."""
    opacity_logits: float = 5e-2
    """Rate of the opacity logits."""
    sh_dc: float = 2.5e-3
    """Rate of the degree-0 colour."""
    sh_rest: float = 1.25e-4
    """Rate of the higher-degree colour coefficients."""


@dataclass
class TrainConfig:
    """How a run optimises: schedule, loss weights, checkpoints."""

    iterations: int = 3000
    """Number of optimisation steps (one training frame each)."""
    lr: LearningRates = field(default_factory=LearningRates)
    """Per-Gaussian learning rates."""
    lambda_dssim: float = 0.2
    """Weight of D-SSIM against L1 in the photometric loss."""
    lambda_depth: float = 0.05
    """Weight of the depth loss (per scene unit of depth error)."""
    depth_loss: Literal["l1", "inverse_l1"] = "l1"
    """Depth loss: L1 on depth, or L1 on inverse depth."""
    regularisation: dict[str, float] = field(default_factory=dict)
    """Weights of the deformation field's regularisers by name (e.g. plane_tv)."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Colour behind all Gaussians (endoscopic scenes are dark)."""
    checkpoint_every: int = 500
    """Write RUN/checkpoints/latest.pt every this many iterations (and at the end, and on Ctrl-C)."""
    seed: int = 0
    """Seed of frame sampling and of densification."""

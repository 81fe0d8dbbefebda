"""Settings of a method besides its components: optimisation, densification, loss weights."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from surgsplat.errors import SurgsplatError
from surgsplat.methods.ranges import dotted


@dataclass
class LearningRates:
    """Adam learning rates of the canonical Gaussians' own parameters. Only the means' rate
    decays; the shapes', opacities' and colours' rates stay constant (3DGS's), since decaying
    them as well cost tissue PSNR (measured: docs/methods/shared-components.md, Learning rates
    of the Gaussians)."""

    means: float = field(default=1.6e-4, metadata={"range": "(0, inf)"})
    """Initial rate of the means, times the scene extent (3DGS convention)."""
    means_final: float = field(default=1.6e-6, metadata={"range": "[0, inf)"})
    """Final rate of the means (exponential decay over the run), times the scene extent."""
    log_scales: float = field(default=5e-3, metadata={"range": "[0, inf)"})
    """Rate of the log-scales."""
    quats: float = field(default=1e-3, metadata={"range": "[0, inf)"})
    """Rate of the rotation quaternions."""
    opacity_logits: float = field(default=5e-2, metadata={"range": "[0, inf)"})
    """Rate of the opacity logits."""
    sh_dc: float = field(default=2.5e-3, metadata={"range": "[0, inf)"})
    """Rate of the degree-0 colour."""
    sh_rest: float = field(default=1.25e-4, metadata={"range": "[0, inf)"})
    """Rate of the higher-degree colour coefficients."""


@dataclass
class TrainConfig:
    """How a run optimises: schedule, background, checkpoints, seed."""

    iterations: int = field(default=3000, metadata={"range": "[1, inf)"})
    """Number of optimisation steps (one training frame each)."""
    lr: LearningRates = field(default_factory=LearningRates)
    """Learning rates of the canonical Gaussians (components set their own)."""
    background: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0),
                                                   metadata={"range": "[0, 1]"})
    """Colour behind all Gaussians (endoscopic scenes are dark)."""
    checkpoint_every: int = field(default=500, metadata={"range": "[1, inf)"})
    """Write RUN/checkpoints/latest.pt every this many iterations (and at the end, and on
    Ctrl-C)."""
    checkpoint_seconds: float = field(default=60.0, metadata={"range": "[0, inf)"})
    """Also write it when this many seconds of wall time have passed since the last one, so a
    kill -9 loses at most about this much training."""
    seed: int = field(default=0, metadata={"range": "[0, 4294967295]"})
    """Seed of frame sampling and of densification."""
    tool_mask_offset_px: int = field(default=0, metadata={"range": "[-100, 100]"})
    """Grow (> 0) or shrink (< 0) the training frames' tool masks by this many pixels before
    training: a mask-robustness test (PhysioSplat's +-10 px); eval scores with the true masks."""
    budget_seconds: float = field(default=0.0, metadata={"range": "[0, inf)"})
    """Train for this many seconds of training steps instead of a fixed count (0 = exactly
    `iterations` steps): `iterations` is then re-planned as the run goes, from the measured
    time per step, so that every stage of the schedule, written as fractions of the run, still
    runs. Scene loading, set-up and checkpoint writes are not counted."""
    coarse_fraction: float = field(default=0.0, metadata={"range": "[0, 1)"})
    """Fraction of the run trained on downscaled frames, coarse to fine (0 = every step at full
    size): the first stage at 1/coarse_factor of the size, each next one at twice the previous
    size, the stages sharing this fraction equally; full size after it."""
    coarse_factor: int = field(default=1, metadata={"range": "[1, 16]"})
    """Downscale factor of the first coarse stage: 1 (no coarse stage), 2, 4, 8 or 16; above 1
    exactly when coarse_fraction is above 0."""

    def check_rules(self, where: str) -> None:
        """SurgsplatError naming the keys (below `where`) unless coarse_factor is a power of 2
        and is above 1 exactly when coarse_fraction is above 0: either one alone trains no
        coarse stage."""
        factor, fraction = dotted(where, "coarse_factor"), dotted(where, "coarse_fraction")
        if self.coarse_factor & (self.coarse_factor - 1):
            raise SurgsplatError(f"{factor}: {self.coarse_factor} is not a power of 2 (1, 2, 4, "
                                 "8 or 16)")
        if (self.coarse_factor > 1) != (self.coarse_fraction > 0):
            raise SurgsplatError(f"{factor} ({self.coarse_factor}) and {fraction} "
                                 f"({self.coarse_fraction}) set the coarse stages together: "
                                 "give both (a factor of 2 to 16 and a fraction above 0) or "
                                 "neither")

    def downscale_at(self, iteration: int) -> int:
        """The factor frames are downscaled by at `iteration` (counted from 1) of this run."""
        stages = self.coarse_factor.bit_length() - 1  # factors coarse_factor, ..., 2
        progress = (iteration - 1) / self.iterations
        if stages == 0 or progress >= self.coarse_fraction:
            return 1
        return self.coarse_factor >> int(progress * stages / self.coarse_fraction)


@dataclass
class LossWeight:
    """The weight of one named loss term in the training objective."""

    weight: float = field(default=1.0, metadata={"range": "[0, inf)"})
    """Multiplier of the term (0 = the term is not computed)."""
    start: float = field(default=0.0, metadata={"range": "[0, 1)"})
    """The term joins the objective once this fraction of the run (of train.iterations) has
    passed, so that `--iters` moves it with the rest of the schedule; in [0, 1)."""
    stop: float = field(default=1.0, metadata={"range": "(0, 1]", "above": "start"})
    """The term leaves the objective after this fraction of the run (1 = it stays to the end);
    greater than start."""

    def window(self, iterations: int) -> tuple[int, int]:
        """(first, last) iteration of a run of `iterations` steps at which the term is active."""
        return iteration_window(self.start, self.stop, iterations)

    def active_at(self, iteration: int, iterations: int) -> bool:
        """Whether the term counts at `iteration` of a run of `iterations` steps."""
        first, last = self.window(iterations)
        return self.weight != 0 and first <= iteration <= last


def iteration_window(start: float, stop: float, iterations: int) -> tuple[int, int]:
    """(first, last) iteration, counted from 1, of the stretch from fraction `start` to fraction
    `stop` of a run of `iterations` steps."""
    return max(round(start * iterations), 1), round(stop * iterations)


@dataclass
class DensifyConfig:
    """When and how Gaussians are added and removed."""

    kind: Literal["threshold", "budget"] = "threshold"
    """Which Gaussians are cloned or split at each densification. threshold (3DGS): those whose
    mean screen-space gradient is above grad_threshold. budget (Taming 3DGS's budgeted
    densification): the count follows a schedule from the initial count to budget_final times
    it at the end of the window, and each densification adds the Gaussians of the highest mean
    gradient that the schedule allows, whatever their gradient."""
    budget_final: float = field(default=1.1, metadata={"range": "[1, 100]"})
    """kind budget: the Gaussian count at the end of the densification window, as a multiple of
    the count when densification starts (within gaussians.max_gaussians)."""
    start: float = field(default=0.1, metadata={"range": "[0, 1]"})
    """Densification may run once this fraction of the run (of train.iterations) has passed."""
    stop: float = field(default=2 / 3, metadata={"range": "[0, 1]", "above": "start"})
    """No densification, pruning or opacity reset after this fraction of the run; greater than
    start."""
    every: int = field(default=100, metadata={"range": "[1, inf)"})
    """Densify and prune every this many iterations (a cadence, not a stage: kept as --iters
    changes, like 3DGS's 100 from 600 to 30000 iterations)."""
    grad_threshold: float = field(default=0.002, metadata={"range": "[0, inf)"})
    """Mean absolute screen-space gradient (NDC-scaled, per visible step) above which a Gaussian
    is densified."""
    percent_dense: float = field(default=0.01, metadata={"range": "[0, inf)"})
    """Gaussians larger than this share of the scene extent are split, smaller ones cloned."""
    split: Literal["long_axis", "sample"] = "long_axis"
    """How a large Gaussian is split in two. long_axis: the children sit at +-d along the
    parent's longest axis s, that axis divided by split_factor to s', the other two kept, with
    d^2 + s'^2 = s^2 so that the pair keeps the parent's extent and spread along that axis.
    sample (3DGS): the children at two random points of the parent's Gaussian, every axis divided
    by split_factor, which can leave part of what the parent covered uncovered, so that a
    densifying step costs more test PSNR than with long_axis (measured:
    docs/benchmarks/speed.md, Densification: how a large Gaussian is split)."""
    split_factor: float = field(default=1.6, metadata={"range": "[1, inf)"})
    """A split Gaussian's children have the parent's scale (long_axis: its longest axis) divided
    by this."""
    min_opacity: float = field(default=0.005, metadata={"range": "[0, 1)"})
    """Prune Gaussians less opaque than this."""
    max_world_scale: float = field(default=0.1, metadata={"range": "(0, inf)"})
    """Prune Gaussians larger than this share of the scene extent."""
    max_screen_radius: float = field(default=0.0, metadata={"range": "[0, inf)"})
    """Prune Gaussians whose projected radius exceeded this many pixels (0 = no limit)."""
    opacity_reset_every: float = field(default=0.0, metadata={"range": "[0, 1]"})
    """Reset opacities to reset_opacity every this fraction of the run while densification runs
    (3DGS: 0.1 of its 30000 iterations; 0 = never). Never by default: resets cost tissue PSNR
    and moved the Gaussians off the surface (measured: docs/methods/shared-components.md,
    Densification)."""
    reset_opacity: float = field(default=0.01, metadata={"range": "(0, 1)"})
    """Opacity ceiling applied by a reset."""

    def window(self, iterations: int) -> tuple[int, int]:
        """(first, last) iteration of a run of `iterations` steps at which densification, pruning
        and opacity resets may run."""
        return iteration_window(self.start, self.stop, iterations)

    def reset_period(self, iterations: int) -> int:
        """Iterations between opacity resets in a run of `iterations` steps (0 = no reset)."""
        if self.opacity_reset_every <= 0:
            return 0
        return max(round(self.opacity_reset_every * iterations), 1)

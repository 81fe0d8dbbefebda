"""Densification and pruning as a Strategy object with explicit state (gsplat's design).

The trainer calls `step_post_backward(...)` after each backward pass; the strategy accumulates
screen-space gradient statistics and, on its schedule, clones small Gaussians with large
gradients, splits large ones, prunes transparent or oversized ones, and resets opacities.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from surgsplat.methods.settings import DensifyConfig
from surgsplat.model.gaussians import GaussianModel
from surgsplat.render.rotation import quaternion_to_matrix
from surgsplat.train.per_gaussian import MOMENT_KEYS, append_gaussians, keep_gaussians


def no_factor() -> None:
    """The opacity factor of a method none of whose components scales opacity."""
    return None


class DensifyStrategy:
    """Densification by threshold (DensifyConfig.kind "threshold"); the budget strategy is a
    subclass that chooses differently. Explicit state: grad_sum [N], visible_count [N],
    max_radius [N] (pixels), the statistics of the screen-space gradients it owns."""

    def __init__(self, config: DensifyConfig, scene_extent: float, max_gaussians: int,
                 iterations: int):
        """iterations: the run's length, which the schedule's fractions refer to."""
        self.config = config
        self.scene_extent = scene_extent
        self.max_gaussians = max_gaussians
        self.reschedule(iterations)
        self.grad_sum = torch.zeros(0)
        self.visible_count = torch.zeros(0)
        self.max_radius = torch.zeros(0)

    def reschedule(self, iterations: int) -> None:
        """Refer the schedule's fractions to a run of `iterations` steps (a run trained to a
        time budget changes its length as it goes)."""
        self.first, self.last = self.config.window(iterations)
        self.reset_period = self.config.reset_period(iterations)

    def state_dict(self) -> dict[str, Tensor | float]:
        return {"grad_sum": self.grad_sum, "visible_count": self.visible_count,
                "max_radius": self.max_radius, "scene_extent": self.scene_extent}

    def load_state_dict(self, state: dict) -> None:
        self.grad_sum = state["grad_sum"]
        self.visible_count = state["visible_count"]
        self.max_radius = state["max_radius"]
        self.scene_extent = float(state["scene_extent"])

    def _ensure_size(self, n: int) -> None:
        if self.grad_sum.shape[0] != n:
            self.grad_sum = torch.zeros(n)
            self.visible_count = torch.zeros(n)
            self.max_radius = torch.zeros(n)

    def gathers_statistics(self, iteration: int) -> bool:
        """Whether step `iteration` feeds densification (its screen-space gradients and radii);
        past the window nothing does, so the trainer need not compute them."""
        return iteration <= self.last

    def step_post_backward(self, iteration: int, model: GaussianModel,
                           optimizer: torch.optim.Optimizer, absgrad: Tensor, image_size: int,
                           radii: Tensor, weights: Tensor | None = None,
                           opacity_factor: Callable[[], Tensor | None] = no_factor) -> None:
        """absgrad [N]: the norm of each Gaussian's screen-space (pixel) position gradient this
        step, which the strategy scales to NDC units by half the image's longer side
        `image_size` (px) and multiplies by `weights` [N] (the components' densification
        weights, None = 1); radii [N] px; opacity_factor() gives the current [N] factor on
        sigmoid(opacity_logits) that rendering applies (None = 1); it is asked only when
        densifying or resetting."""
        config = self.config
        if not self.gathers_statistics(iteration):
            return
        screen_grad = absgrad * (0.5 * image_size)
        if weights is not None:
            screen_grad = screen_grad * weights
        self._ensure_size(model.num_gaussians)
        visible = radii > 0  # masked sums, not boolean indexing: no nonzero() per step
        self.grad_sum += torch.where(visible, screen_grad, 0.0)
        self.visible_count += visible
        self.max_radius = torch.maximum(self.max_radius, radii.float())
        if iteration >= self.first and iteration % config.every == 0:
            self._densify(iteration, model, optimizer, opacity_factor())
            self._prune(model, optimizer, opacity_factor())
            self._ensure_size(model.num_gaussians)
            self.grad_sum.zero_()
            self.visible_count.zero_()
            self.max_radius.zero_()
        if self.reset_period and iteration % self.reset_period == 0:
            self._reset_opacity(model, optimizer)

    @torch.no_grad()
    def _densify(self, iteration: int, model: GaussianModel,
                 optimizer: torch.optim.Optimizer, factor: Tensor | None) -> None:
        config = self.config
        room = self.room(model.num_gaussians, iteration)
        if room <= 0:
            return
        mean_grad = self.grad_sum / self.visible_count.clamp_min(1)
        max_scale = model.params["log_scales"].exp().max(dim=1).values
        large = max_scale > config.percent_dense * self.scene_extent
        clone_idx, split_idx = self.chosen(mean_grad, large, room)
        if clone_idx.numel():
            self._share_opacity(model, clone_idx, None if factor is None else factor[clone_idx])
        rows = {name: value[clone_idx] for name, value in model.per_gaussian().items()}
        split_rows = self._split_rows(model, split_idx)
        new_rows = {name: torch.cat([rows[name], split_rows[name]]) for name in rows}
        if new_rows["means"].shape[0] == 0:
            return
        append_gaussians(model, optimizer, new_rows)
        if split_idx.numel():
            # The split parents are replaced by their two children: drop the parents.
            keep = torch.ones(model.num_gaussians, dtype=torch.bool)
            keep[split_idx] = False
            keep_gaussians(model, optimizer, keep)

    def room(self, count: int, iteration: int) -> int:
        """How many Gaussians the densification at `iteration` may add to `count`: up to the
        budget max_gaussians."""
        return self.max_gaussians - count

    def chosen(self, mean_grad: Tensor, large: Tensor, room: int) -> tuple[Tensor, Tensor]:
        """(clone indices, split indices) of this densification: the Gaussians whose mean
        gradient (of mean_grad [N]) is above grad_threshold, small ones (not `large` [N]) cloned
        and large ones split, the strongest first within `room` (a split adds one net)."""
        candidates = mean_grad > self.config.grad_threshold
        clone, split = candidates & ~large, candidates & large
        clone_idx = _strongest(clone, mean_grad, room)
        split_idx = _strongest(split, mean_grad, max(room - clone_idx.numel(), 0) // 2)
        return clone_idx, split_idx

    @staticmethod
    def _share_opacity(model: GaussianModel, index: Tensor, factor: Tensor | None) -> None:
        """Give the Gaussians about to be cloned the rendered opacity o' = 1 - sqrt(1 - o), so
        that the original and its copy composite to the original opacity o (as 3DGS-MCMC does):
        cloning then adds capacity without changing the image, which matters on short CPU
        schedules. factor [K]: the rendered opacity is sigmoid(logit) * factor."""
        logits = model.params["opacity_logits"]
        factor = torch.ones(index.numel()) if factor is None else factor.clamp_min(1e-6)
        opacity = torch.sigmoid(logits[index]) * factor
        shared = (1.0 - torch.sqrt(1.0 - opacity)) / factor
        logits[index] = torch.logit(shared.clamp(1e-6, 1.0 - 1e-6))

    def _split_rows(self, model: GaussianModel, index: Tensor) -> dict[str, Tensor]:
        """Two children per parent of `index` [K], each parent's pair adjacent (every
        per-Gaussian parameter and buffer); placed as DensifyConfig.split says."""
        parents = {name: value[index] for name, value in model.per_gaussian().items()}
        children = {name: value.repeat_interleave(2, dim=0) for name, value in parents.items()}
        scales = parents["log_scales"].exp()  # [K, 3]
        rotation = quaternion_to_matrix(parents["quats"])  # [K, 3, 3], columns: the local axes
        shrink = 1.0 / self.config.split_factor
        if self.config.split == "long_axis":
            axis = scales.argmax(dim=1)  # [K]
            direction = rotation[torch.arange(index.numel()), :, axis]  # [K, 3]
            reach = scales.gather(1, axis[:, None]) * math.sqrt(1.0 - shrink ** 2)  # [K, 1]
            offsets = torch.stack([direction * reach, -direction * reach], dim=1).reshape(-1, 3)
            log_scales = children["log_scales"].clone()
            rows = torch.arange(2 * index.numel())
            log_scales[rows, axis.repeat_interleave(2)] += math.log(shrink)
        else:
            local = torch.randn(index.numel() * 2, 3) * scales.repeat_interleave(2, dim=0)
            offsets = (rotation.repeat_interleave(2, dim=0) @ local[..., None])[..., 0]
            log_scales = children["log_scales"] + math.log(shrink)
        children["means"] = children["means"] + offsets
        children["log_scales"] = log_scales
        return children

    @torch.no_grad()
    def _prune(self, model: GaussianModel, optimizer: torch.optim.Optimizer,
               factor: Tensor | None) -> None:
        config = self.config
        opacity = torch.sigmoid(model.params["opacity_logits"])
        if factor is not None:
            opacity = opacity * factor
        prune = opacity < config.min_opacity
        max_scale = model.params["log_scales"].exp().max(dim=1).values
        prune |= max_scale > config.max_world_scale * self.scene_extent
        if config.max_screen_radius > 0 and self.max_radius.shape[0] == prune.shape[0]:
            prune |= self.max_radius > config.max_screen_radius
        if prune.all():
            prune[torch.argmax(opacity)] = False
        if prune.any():
            keep_gaussians(model, optimizer, ~prune)

    @torch.no_grad()
    def _reset_opacity(self, model: GaussianModel, optimizer: torch.optim.Optimizer) -> None:
        """Clamp sigmoid(opacity_logits) to the reset value: with factors in (0, 1] the rendered
        opacity is then at most that value too."""
        ceiling = math.log(self.config.reset_opacity / (1 - self.config.reset_opacity))
        logits = model.params["opacity_logits"]
        logits.clamp_(max=ceiling)
        for key in MOMENT_KEYS:
            moment = optimizer.state.get(logits, {}).get(key)
            if moment is not None:
                moment.zero_()


class BudgetStrategy(DensifyStrategy):
    """Budgeted densification (DensifyConfig.kind "budget", after Taming 3DGS): the Gaussian
    count grows on a schedule, linearly over the densification window from the count at its
    first densification to budget_final times that count, and each densification adds the
    Gaussians of highest mean gradient that the schedule allows, without a threshold. Extra
    state: start_count, the count at the first densification (0 until then)."""

    def __init__(self, config: DensifyConfig, scene_extent: float, max_gaussians: int,
                 iterations: int):
        super().__init__(config, scene_extent, max_gaussians, iterations)
        self.start_count = 0

    def state_dict(self) -> dict[str, Tensor | float]:
        return {**super().state_dict(), "start_count": self.start_count}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.start_count = int(state["start_count"])

    def room(self, count: int, iteration: int) -> int:
        """The count scheduled at `iteration` less `count`, within max_gaussians."""
        if self.start_count == 0:
            self.start_count = count
        progress = min(max((iteration - self.first) / max(self.last - self.first, 1), 0.0),
                       1.0)
        target = self.start_count * (1.0 + (self.config.budget_final - 1.0) * progress)
        return min(int(target), self.max_gaussians) - count

    def chosen(self, mean_grad: Tensor, large: Tensor, room: int) -> tuple[Tensor, Tensor]:
        """The `room` Gaussians of highest mean gradient among those seen (each adds one net:
        a clone, or two split children in place of their parent), small ones cloned and large
        ones split."""
        index = _strongest(self.visible_count > 0, mean_grad, room)
        return index[~large[index]], index[large[index]]


STRATEGIES = {"threshold": DensifyStrategy, "budget": BudgetStrategy}
"""The densification strategy of each DensifyConfig.kind."""


def build_strategy(config: DensifyConfig, scene_extent: float, max_gaussians: int,
                   iterations: int) -> DensifyStrategy:
    """The strategy that config.kind names, for a run of `iterations` steps."""
    return STRATEGIES[config.kind](config, scene_extent, max_gaussians, iterations)


def _strongest(candidates: Tensor, score: Tensor, limit: int) -> Tensor:
    """Indices of at most `limit` candidates [N] bool, highest score first."""
    index = candidates.nonzero()[:, 0]
    if index.numel() > limit:
        index = index[torch.topk(score[index], limit).indices]
    return index

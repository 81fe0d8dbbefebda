"""The component contract is enough for a new method: a toy component defined here, outside
`surgsplat/`, owns a per-Gaussian scalar, renders it as a channel, and supervises it with its own
loss. It trains, is densified with the Gaussians, is checkpointed, resumes exactly, and is
loaded back from its run folder, without any change to surgsplat's code."""

from __future__ import annotations

import json
from dataclasses import dataclass

import torch
from torch import Tensor

from surgsplat.data.scene import load_scene
from surgsplat.methods.registry import method_config
from surgsplat.methods.settings import LossWeight
from surgsplat.model.component import (Component, ComponentConfig, FrameTime, RenderContext,
                                       SetupContext)
from surgsplat.model.dynamic import render_frame
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import CHECKPOINT, CONFIG_FILE, LOG_FILE, Trainer

ATTRIBUTE = "toy_logit"
TARGET = 0.25


@dataclass
class ToyConfig(ComponentConfig, kind="toy_scalar"):
    """A per-Gaussian scalar in (0, 1), rendered as channel "toy"."""

    init_logit: float = 2.0
    """Initial logit of every Gaussian's scalar."""
    lr: float = 0.05
    """Adam learning rate of the logits."""

    def build(self) -> "ToyComponent":
        return ToyComponent(self)


class ToyComponent(Component):
    def __init__(self, config: ToyConfig):
        super().__init__()
        self.config = config

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        return {ATTRIBUTE: torch.full((context.points.shape[0],), self.config.init_logit)}

    def attribute_lrs(self) -> dict[str, float]:
        return {ATTRIBUTE: self.config.lr}

    def render_channels(self, state, gaussians, camera, when) -> dict[str, Tensor]:
        return {"toy": torch.sigmoid(gaussians.params[ATTRIBUTE])}

    def loss_names(self) -> tuple[str, ...]:
        return ("toy",)

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        rendered = context.output.extras["toy"][..., 0]
        covered = context.output.alpha.detach()
        return {"toy": ((rendered - TARGET * covered) ** 2)[context.frame.tissue].mean()}


def toy_method(iterations: int):
    config = method_config("deform3dgs")
    config.components["toy"] = ToyConfig()
    config.losses["toy"] = LossWeight(1.0)
    config.train.iterations = iterations
    config.init.max_points = 3000
    config.densify.start = 0.0
    config.densify.every = 10
    config.train.checkpoint_every = 1000
    return config


def toy_error(model, scene) -> float:
    frame = scene.frames[0]
    out = render_frame(model, frame.camera, FrameTime(frame.index, frame.time))
    covered = out.alpha > 0.9
    return float((out.extras["toy"][..., 0][covered] / out.alpha[covered] - TARGET).abs().mean())


def test_toy_component_trains_checkpoints_resumes_and_loads(small_phantom, tmp_path):
    scene = load_scene(small_phantom)
    straight = Trainer(toy_method(40), scene, tmp_path / "straight")
    initial_error = toy_error(straight.model, scene)
    initial_count = straight.model.gaussians.num_gaussians
    straight.fit()
    assert toy_error(straight.model, scene) < 0.5 * initial_error
    # densification changed the count and carried the toy attribute along
    params = straight.model.gaussians.params
    assert params[ATTRIBUTE].shape[0] == params["means"].shape[0] != initial_count
    log = [json.loads(line) for line in (tmp_path / "straight" / LOG_FILE).read_text().splitlines()]
    assert all("toy" in entry["terms"] for entry in log)
    saved = json.loads((tmp_path / "straight" / CONFIG_FILE).read_text())
    assert saved["components"]["toy"]["kind"] == "toy_scalar"

    interrupted = Trainer(toy_method(40), scene, tmp_path / "resumed")

    def stop_at_20(stats):
        if stats.iteration == 20:
            raise KeyboardInterrupt

    try:
        interrupted.fit(stop_at_20)
    except KeyboardInterrupt:
        pass
    resumed = Trainer(toy_method(40), scene, tmp_path / "resumed")
    resumed.load(tmp_path / "resumed" / CHECKPOINT)
    assert resumed.iteration == 20
    resumed.fit()
    for name, value in straight.model.gaussians.params.items():
        torch.testing.assert_close(resumed.model.gaussians.params[name], value,
                                   rtol=1e-4, atol=1e-5, msg=name)

    run = load_trained_run(tmp_path / "straight")
    assert isinstance(run.model.components["toy"], ToyComponent)
    torch.testing.assert_close(run.model.gaussians.params[ATTRIBUTE], params[ATTRIBUTE].detach())
    assert toy_error(run.model, scene) == toy_error(straight.model, scene)


@dataclass
class FrozenGrowthConfig(ComponentConfig, kind="toy_frozen_growth"):
    """Weights every Gaussian's densification gradient by 0 and halves every opacity."""

    def build(self) -> "FrozenGrowthComponent":
        return FrozenGrowthComponent()


class FrozenGrowthComponent(Component):
    def transform(self, state, gaussians, when):
        return state.replace(opacities=state.opacities * 0.5)

    def opacity_factor(self, gaussians) -> Tensor:
        return torch.full((gaussians.num_gaussians,), 0.5)

    def densify_weights(self, context: RenderContext) -> Tensor:
        return torch.zeros(context.gaussians.num_gaussians)


def test_densify_weights_and_opacity_factor_reach_the_strategy(small_phantom, tmp_path):
    """A component's zero densification weights stop all growth; its opacity factor makes
    pruning see the halved opacity (min_opacity 0.3 prunes every Gaussian below 0.6 logit
    opacity, which it would not do on the logits alone)."""
    scene = load_scene(small_phantom)
    config = toy_method(10)
    config.components["frozen"] = FrozenGrowthConfig()
    config.densify.start, config.densify.stop, config.densify.every = 0.0, 1.0, 5
    config.densify.grad_threshold = 0.0
    config.densify.min_opacity = 0.3
    trainer = Trainer(config, scene, tmp_path / "frozen")
    with torch.no_grad():
        trainer.model.gaussians.params["opacity_logits"][::2] = torch.logit(torch.tensor(0.55))
        trainer.model.gaussians.params["opacity_logits"][1::2] = torch.logit(torch.tensor(0.95))
    count = trainer.model.gaussians.num_gaussians
    for _ in range(5):
        trainer.step()
    remaining = trainer.model.gaussians.num_gaussians
    assert remaining < count  # rendered 0.275 < 0.3 pruned; no clone or split added any
    assert remaining >= count // 2 - 1
    assert torch.all(torch.sigmoid(trainer.model.gaussians.params["opacity_logits"]) > 0.6)

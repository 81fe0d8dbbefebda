"""The component contract is enough for a new method: a toy component defined here, outside
`surgsplat/`, owns a per-Gaussian scalar and a per-Gaussian buffer, renders the scalar as a
channel, and supervises it with its own loss. It trains, is densified with the Gaussians, is
checkpointed, resumes exactly, and is loaded back from its run folder, without any change to
surgsplat's code."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import Tensor

from surgsplat.data.scene import load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.eval.run_metrics import METRICS_FILE, EvalOptions
from surgsplat.export.report import frame_strip, strip_channels, write_report
from surgsplat.export.viewer import view_image, viewer_channels
from surgsplat.methods.registry import method_config
from surgsplat.methods.settings import LossWeight
from surgsplat.model.capabilities import DensifyWeighting, OpacityFactor, ToolMembership
from surgsplat.model.channels import ChannelDescriptor, ChannelKind, Colormap
from surgsplat.model.component import (Component, ComponentConfig, Diagnostics, FrameTime,
                                       RenderContext, SetupContext)
from surgsplat.model.dynamic import render_frame
from surgsplat.model.phases import Phase
from surgsplat.pipeline.evaluate import evaluate
from surgsplat.pipeline.render import write_run_videos
from surgsplat.pipeline.train import train_run
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import CHECKPOINT, CONFIG_FILE, LOG_FILE, Trainer

PACKAGE = Path(__file__).resolve().parents[2] / "surgsplat"
ATTRIBUTE = "toy_logit"
BUFFER = "toy_origin"
"""The toy's per-Gaussian buffer: the row each Gaussian (or its ancestor) started in."""
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
    phase = Phase.LOSS

    def __init__(self, config: ToyConfig):
        super().__init__()
        self.config = config

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        rows = context.points.shape[0]
        return {ATTRIBUTE: torch.full((rows,), self.config.init_logit),
                BUFFER: torch.arange(rows)}

    def attribute_lrs(self) -> dict[str, float]:
        return {ATTRIBUTE: self.config.lr}  # the buffer has none: it is state, not learnt

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
    # densification changed the count and carried the toy attribute and buffer along; the
    # buffer has no optimiser group
    params, buffers = straight.model.gaussians.params, straight.model.gaussians.buffer_dict
    assert params[ATTRIBUTE].shape[0] == params["means"].shape[0] != initial_count
    assert buffers[BUFFER].shape[0] == params["means"].shape[0]
    assert int(buffers[BUFFER].max()) < initial_count
    assert BUFFER not in [group["name"] for group in straight.optimizer.param_groups]
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
    assert torch.equal(resumed.model.gaussians.buffer_dict[BUFFER], buffers[BUFFER])

    run = load_trained_run(tmp_path / "straight")
    assert isinstance(run.model.components["toy"], ToyComponent)
    torch.testing.assert_close(run.model.gaussians.params[ATTRIBUTE], params[ATTRIBUTE].detach())
    assert torch.equal(run.model.gaussians.buffer_dict[BUFFER], buffers[BUFFER])
    assert toy_error(run.model, scene) == toy_error(straight.model, scene)


@dataclass
class FrozenGrowthConfig(ComponentConfig, kind="toy_frozen_growth"):
    """Weights every Gaussian's densification gradient by 0 and halves every opacity."""

    def build(self) -> "FrozenGrowthComponent":
        return FrozenGrowthComponent()


class FrozenGrowthComponent(Component):
    phase = Phase.OPACITY
    provides = (OpacityFactor, DensifyWeighting)

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


@dataclass
class FrameClockConfig(ComponentConfig, kind="toy_frame_clock"):
    """Contributes two metrics of its own to metrics.json, with their conventions."""

    label: str = "time"
    """Word the conventions use for a frame's time."""

    def build(self) -> "FrameClockComponent":
        return FrameClockComponent(self)


class FrameClockComponent(Component):
    phase = Phase.LOSS

    def __init__(self, config: FrameClockConfig):
        super().__init__()
        self.config = config

    def frame_diagnostics(self, state, gaussians, when) -> Diagnostics:
        return Diagnostics(summed={"clock_frames": 1}, averaged={"clock_time": when.time},
                           conventions={"clock_time": f"the test frames' {self.config.label}, "
                                                      "mean",
                                        "clock_frames": "test frames seen"})


def test_a_component_contributes_metrics_and_their_conventions(small_phantom, tmp_path):
    """A component defined here reaches metrics.json through `surgsplat eval`'s pipeline: its
    averaged and summed metrics, the frames they cover, and the conventions its config words."""
    config = toy_method(4)
    config.components["clock"] = FrameClockConfig(label="clock reading")
    train_run(config, small_phantom, tmp_path / "run", resume=False)
    run = load_trained_run(tmp_path / "run")
    evaluate(run, EvalOptions(geometry=False))
    metrics = json.loads((tmp_path / "run" / METRICS_FILE).read_text())
    times = [frame.time for frame in run.scene.test_frames]
    assert metrics["clock_time"] == pytest.approx(sum(times) / len(times))
    assert metrics["clock_frames"] == metrics["frames_covered"]["diagnostics"] == len(times)
    assert metrics["conventions"]["clock_time"] == "the test frames' clock reading, mean"
    assert metrics["conventions"]["clock_frames"] == "test frames seen"


MARK = "toy_tool_mark"
"""The channel of ToolMarkComponent: named by no file under surgsplat/."""


@dataclass
class ToolMarkConfig(ComponentConfig, kind="toy_tool_mark"):
    """Marks the Gaussians on the positive side of x = 0 as tool and renders that mark."""

    def build(self) -> "ToolMarkComponent":
        return ToolMarkComponent()


class ToolMarkComponent(Component):
    phase = Phase.LOSS
    provides = (ToolMembership,)

    def tool_members(self, gaussians) -> Tensor:
        return gaussians.params["means"].detach()[:, 0] > 0

    def render_channels(self, state, gaussians, camera, when) -> dict[str, Tensor]:
        return {MARK: self.tool_members(gaussians).float()}

    def channel_descriptors(self) -> tuple[ChannelDescriptor, ...]:
        return (ChannelDescriptor(MARK, ChannelKind.PROBABILITY, Colormap.INFERNO),)


def test_a_component_declares_tool_members_and_a_channel_that_videos_viewer_and_report_show(
        small_phantom, tmp_path):
    """A component defined here says which Gaussians are tool, and adds a channel with its
    descriptor: the model's membership is its, and the channel becomes a video, a choice of the
    viewer and a panel of the report, without surgsplat naming it."""
    assert not [path for path in PACKAGE.rglob("*.py") if MARK in path.read_text()]
    config = toy_method(4)
    config.components["mark"] = ToolMarkConfig()
    Trainer(config, load_scene(small_phantom), tmp_path / "run").fit()
    run = load_trained_run(tmp_path / "run")
    tool = run.model.gaussians.params["means"].detach()[:, 0] > 0
    assert 0 < int(tool.sum()) < tool.numel()
    assert torch.equal(run.model.tool_members(), tool)
    assert torch.equal(run.model.tissue_members(), ~tool)

    paths = write_run_videos(run, tmp_path / "videos", 5.0, ("rgb", MARK))
    assert [path.name for path in paths] == ["rgb.mp4", f"{MARK}.mp4"]
    assert all(path.stat().st_size > 0 for path in paths)
    with pytest.raises(SurgsplatError, match=f"--channels: .*{MARK}.*got rgb, albedo"):
        write_run_videos(run, tmp_path / "videos", 5.0, ("rgb", "albedo"))

    assert MARK in viewer_channels(run.model)
    frame = run.scene.frames[0]
    image = view_image(run, frame.camera, 0, MARK)
    assert image.shape == (frame.camera.height, frame.camera.width, 3)
    assert image.dtype == np.uint8 and image.std() > 10  # the marked half stands out

    assert MARK in [channel.name for channel in strip_channels(run.model)]
    strip = frame_strip(run, run.scene.test_frames[0])
    assert strip.shape[1] == (3 + len(strip_channels(run.model))) * frame.camera.width
    (tmp_path / "run" / METRICS_FILE).write_text(json.dumps({"psnr_tissue": 20.0}))
    page = write_report([tmp_path / "run"], tmp_path / "report.html", max_frames=1).read_text()
    assert f"| {MARK}</figcaption>" in page

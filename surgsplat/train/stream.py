"""Training while the clip arrives: a Trainer whose scene grows frame by frame.

A StreamTrainer starts from the first frame (its depth gives the initial Gaussians, as for an
offline run) and `integrate`s every later frame as it comes:
- the frame's time is its index over the stream's horizon (the frames the time axis is set up
  for; a stream that outgrows it doubles it, compressing the earlier frames' time, and `finish`
  fits it to the frames that came, so that the run is an ordinary one: frame i at i / N);
- a training frame is trained on at the next step, before any replay; that step's render gives
  its PSNR on arrival and the tissue pixels the model does not explain (rendered too
  transparent, or off the frame's measured depth): Gaussians are added there, at the frame's
  depth where it has one, else at the rendered depth (a test frame is rendered on arrival for
  its PSNR).

Between arrivals each step replays a seen training frame: one of the `recent_frames` latest with
probability `recent_share`, else any, so that the earliest frames are not forgotten. The
schedules are written for a run of unknown length: the learning rates stay at `lr_progress` of
their decay while frames arrive and decay to their final values over the polish that may follow
the last frame (`start_polish`); densification runs every DensifyConfig.every full-size steps
from `densify_after_steps` on.

A component that follows the clip's time can stream only if it can follow the time axis as it
grows (`capabilities.Retimable`); loss terms with a window (a fraction of the run) cannot: a
stream has no length to take a fraction of. `check_streamable` says which one stops a method.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import torch

from surgsplat.data.scene import MIN_SIZE, Frame, Scene
from surgsplat.errors import SurgsplatError
from surgsplat.image.pinhole import backproject
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.registry import PRESETS
from surgsplat.model.capabilities import Retimable
from surgsplat.model.component import Component, FrameTime, SceneInfo, SetupContext
from surgsplat.model.dynamic import render_frame
from surgsplat.model.gaussians import GaussianModel
from surgsplat.render.render import RenderOutput
from surgsplat.train.checkpoint import build_components
from surgsplat.train.per_gaussian import append_gaussians
from surgsplat.train.trainer import StepStats, Trainer, declared_per_gaussian, tissue_psnr

DEFAULT_HORIZON = 128
"""Frames a stream's time axis is set up for when the source does not say how many it sends."""


@dataclass
class StreamConfig:
    """How a stream is trained (see the module docstring)."""

    recent_frames: int = field(default=8, metadata={"range": "[1, inf)"})
    """The latest training frames that replay favours."""
    recent_share: float = field(default=0.2, metadata={"range": "[0, 1]"})
    """Share of the replay steps spent on the `recent_frames` latest frames (the rest replay
    any seen frame alike)."""
    lr_progress: float = field(default=0.0, metadata={"range": "[0, 1]"})
    """Where the decaying learning rates are held while frames arrive, from 0 (initial) to 1
    (final); the polish decays them from here to 1. A stream's model is far from converged
    while frames come: the initial rates serve it best."""
    densify_after_steps: int = field(default=100, metadata={"range": "[1, inf)"})
    """Densification starts after this many steps."""
    downscale: int = field(default=2, metadata={"range": "[1, 16]"})
    """Frames are trained on at 1 / downscale of their size while they arrive (the polish
    trains at full size): cheaper steps, more of them per arrival."""
    add_alpha_below: float = field(default=0.5, metadata={"range": "[0, 1]"})
    """Tissue pixels of a new frame rendered less opaque than this get new Gaussians: the
    model has nothing there yet."""
    add_depth_error: float = field(default=0.05, metadata={"range": "(0, inf)"})
    """Tissue pixels whose rendered depth is off the frame's measured depth by more than this
    fraction of it get new Gaussians: the surface there is not where the model has one (a
    colour error alone is left to the training steps)."""
    add_stride: int = field(default=2, metadata={"range": "[1, inf)"})
    """New Gaussians come from every add_stride-th pixel in x and y."""


def check_streamable(config: MethodConfig, components: Mapping[str, Component]) -> None:
    """SurgsplatError naming what keeps `config`'s method (built as `components`) from
    training on a stream, and the methods that can."""
    problem = stream_problem(config, components)
    if problem is not None:
        raise SurgsplatError(f"method {config.name!r} cannot stream: {problem} (methods that "
                             f"stream: {', '.join(streamable_methods()) or 'none'})")


def stream_problem(config: MethodConfig, components: Mapping[str, Component]) -> str | None:
    """What keeps `config`'s method (built as `components`) from training on a stream: a
    component that follows the clip's time but cannot follow its growth, or a loss term active
    over a fraction of the run; None when nothing does."""
    for name, component in components.items():
        if component.reads_time and Retimable not in component.provides:
            return (f"its component {name!r} follows the clip's time but cannot follow a clip "
                    "that grows")
    for name, weight in config.losses.items():
        if weight.weight > 0 and (weight.start > 0 or weight.stop < 1):
            return (f"loss term {name!r} is active over a fraction of the run ({weight.start:g} "
                    f"to {weight.stop:g}), and a stream has no length; --set "
                    f"losses.{name}.start=0 --set losses.{name}.stop=1 lifts it")
    return None


def streamable_methods() -> list[str]:
    """The registered methods that can train on a stream, as their presets stand."""
    names = []
    for name, preset in PRESETS.items():
        config = preset.build().resolved(SceneInfo(DEFAULT_HORIZON, MIN_SIZE, MIN_SIZE, ()))
        if stream_problem(config, build_components(config)) is None:
            names.append(name)
    return names


@dataclass
class FrameRecord:
    """What the stream log says of one frame."""

    index: int
    arrival: float  # seconds since the stream started
    is_test: bool
    trained_at: float | None = None  # seconds since the stream started; None = not yet
    psnr_arrival: float | None = None  # tissue PSNR of the model as the frame arrived
    psnr_integrated: float | None = None  # at its last step before it left the recent frames
    psnr_final: float | None = None
    added_gaussians: int = 0

    @property
    def lag(self) -> float | None:
        """Seconds from arrival to the first step on the frame."""
        return None if self.trained_at is None else self.trained_at - self.arrival


class StreamTrainer(Trainer):
    """A Trainer of a scene that grows; see the module docstring. `scene` holds the first
    frame; `horizon` is the number of frames the time axis is set up for."""

    def __init__(self, config: MethodConfig, scene: Scene, run_dir: Path, horizon: int,
                 stream: StreamConfig, started: float):
        self.horizon = max(horizon, 2)
        first = scene.frames[0]
        first.time = 0.0
        info = SceneInfo(num_frames=self.horizon, width=scene.width, height=scene.height,
                         train_indices=tuple(range(self.horizon)))
        super().__init__(config, scene, run_dir, info=info)
        check_streamable(self.config, self.model.components)
        self.stream = stream
        self.started = started  # time.monotonic() of the stream's start
        self.records: dict[int, FrameRecord] = {}
        self._fresh: deque[Frame] = deque()  # training frames not yet trained on
        self._polish: tuple[int, int] | None = None  # (first step, last step) of the polish
        self.strategy.first = stream.densify_after_steps
        self.strategy.last = sys.maxsize
        self.strategy.reset_period = 0
        self._replay = torch.Generator().manual_seed(self.config.train.seed)
        self._train_indices: list[int] = [] if first.is_test else [0]
        self._stepped = -1  # the frame of the latest step
        self._record(first)

    # ---- arrivals ----
    def integrate(self, frame: Frame, arrival: float) -> None:
        """Add the arrived `frame` (index len(scene.frames)) to the scene: its time, its record
        with its PSNR on arrival, and Gaussians where the model does not explain it."""
        if frame.index != len(self.scene.frames):
            raise ValueError(f"frame {frame.index} arrived after {len(self.scene.frames)} frames")
        while frame.index >= self.horizon:
            self._double_horizon()
        frame.time = frame.index / self.horizon
        self.scene.frames.append(frame)
        self._record(frame, arrival=arrival)
        if not frame.is_test:
            self._train_indices.append(frame.index)

    def _record(self, frame: Frame, arrival: float | None = None) -> None:
        """The frame's record; a test frame's PSNR on arrival (a training frame's comes with
        its first step, `step`); a training frame waits for that step."""
        arrival = time.monotonic() if arrival is None else arrival
        record = FrameRecord(frame.index, arrival - self.started, frame.is_test)
        self.records[frame.index] = record
        if frame.is_test:
            with torch.no_grad():
                output = render_frame(self.model, frame.camera, self._when(frame),
                                      self.background)
            record.psnr_arrival = tissue_psnr(output.rgb, frame)
        else:
            self._fresh.append(frame)

    def _when(self, frame: Frame) -> FrameTime:
        return FrameTime(frame.index, frame.time)

    def _double_horizon(self) -> None:
        self.retime(self.horizon * 2)

    def retime(self, horizon: int) -> None:
        """Set the time axis up for `horizon` frames: every Retimable component follows, and
        frame i's time becomes i / horizon."""
        factor = self.horizon / horizon
        for component in self.model.providers(Retimable):
            component.retime(self.model.gaussians, factor)
        self.horizon = horizon
        for frame in self.scene.frames:
            frame.time = frame.index / horizon

    @torch.no_grad()
    def _add_gaussians(self, frame: Frame, output: RenderOutput) -> int:
        """Gaussians at the tissue pixels of `frame` that `output` (its render) does not
        explain; returns how many were added (none past the Gaussian budget)."""
        stream = self.stream
        alpha, rendered = output.alpha.detach(), output.depth.detach()
        wanted = frame.tissue & (alpha < stream.add_alpha_below)
        if frame.depth is not None:
            measured = frame.depth
            off = (rendered - measured).abs() > stream.add_depth_error * measured
            wanted |= frame.tissue & (measured > 0) & off
        stride = torch.zeros_like(wanted)
        stride[::stream.add_stride, ::stream.add_stride] = True
        wanted &= stride
        room = self.strategy.max_gaussians - self.model.gaussians.num_gaussians
        if room <= 0 or not wanted.any():
            return 0
        depth = frame.depth if frame.depth is not None else torch.zeros_like(rendered)
        # the render's depth where it is opaque enough to count, for pixels without a measure
        rendered = rendered.where(alpha >= stream.add_alpha_below, torch.zeros_like(rendered))
        if not bool((rendered > 0).any()):
            return 0
        fallback = rendered.where(rendered > 0, rendered[rendered > 0].median())
        depth = depth.where(depth > 0, fallback)
        camera = self.model.camera_at(frame.camera, self._when(frame))
        means = backproject(depth, camera.K, wanted, camera.camera_to_world)
        colors = frame.image[wanted]
        # each stands for a stride x stride patch of pixels at its depth
        sizes = depth[wanted] * (stream.add_stride / camera.fx)
        if means.shape[0] > room:
            keep = torch.randperm(means.shape[0], generator=self._replay)[:room]
            means, colors, sizes = means[keep], colors[keep], sizes[keep]
        self._append(means, colors, sizes)
        return int(means.shape[0])

    def _append(self, means: torch.Tensor, colors: torch.Tensor, sizes: torch.Tensor) -> None:
        """Append Gaussians at `means` [M, 3] with `colors` [M, 3] and isotropic scales
        `sizes` [M] (scene units), every component's initial attributes with them (as the
        initial points get)."""
        context = SetupContext(scene=SceneInfo(self.horizon, self.scene.width,
                                               self.scene.height, ()),
                               points=means, scene_extent=self.scene_extent, frames=())
        attributes, buffers = declared_per_gaussian(context, self.model.components)
        fresh = GaussianModel.from_points(means, colors, self.config.gaussians, attributes,
                                          buffers)
        rows = {name: value.detach() for name, value in fresh.per_gaussian().items()}
        rows["log_scales"] = sizes.clamp_min(1e-6).log()[:, None].expand(-1, 3).contiguous()
        append_gaussians(self.model.gaussians, self.optimizer, rows)

    # ---- steps ----
    @property
    def has_fresh_frames(self) -> bool:
        """Whether a training frame has arrived and not yet been trained on."""
        return bool(self._fresh)

    @property
    def has_frames_to_train(self) -> bool:
        return bool(self._train_indices)

    def _next_frame(self) -> Frame:
        if self._fresh:
            frame = self._fresh.popleft()
            record = self.records[frame.index]
            if record.trained_at is None:
                record.trained_at = time.monotonic() - self.started
        else:  # the polish replays every frame alike
            seen = self._train_indices
            recent = self._polish is None and \
                float(torch.rand(1, generator=self._replay)) < self.stream.recent_share
            pool = seen[-self.stream.recent_frames:] if recent else seen
            frame = self.scene.frames[pool[int(torch.randint(len(pool), (1,),
                                                             generator=self._replay))]]
        self._stepped = frame.index
        return frame

    def step(self) -> StepStats:
        """One step. A frame's first step gives its PSNR on arrival, and its render the pixels
        that get new Gaussians (`_add_gaussians`; not for the first frame, which the initial
        points came from). Its PSNR in its first step, and in every later one while it is
        among the recent frames, is its PSNR as integrated."""
        first = self._fresh[0].index if self._fresh else None
        stats = super().step()
        record = self.records[self._stepped]
        if self._stepped == first:
            record.psnr_arrival = stats.psnr
            if first > 0:
                at_step_size = self._at_step_size(self.scene.frames[first])
                record.added_gaussians = self._add_gaussians(at_step_size, self.last_output)
        if self._stepped == first or \
                self._stepped in self._train_indices[-self.stream.recent_frames:]:
            record.psnr_integrated = stats.psnr
        return stats

    def downscale_factor(self) -> int:
        return 1 if self._polish is not None else self.stream.downscale

    def lr_progress(self) -> float:
        held = self.stream.lr_progress
        if self._polish is None:
            return held
        first, last = self._polish
        done = min(max(self.iteration - first, 0) / max(last - first, 1), 1.0)
        return held + (1.0 - held) * done

    def start_polish(self, steps: int) -> None:
        """The next `steps` steps are the polish: full-size frames, the rates decaying to their
        final values, densification over the polish's first DensifyConfig.stop of its steps
        (as over an offline run's)."""
        self._polish = (self.iteration, self.iteration + steps)
        self.strategy.first = self.iteration + 1
        self.strategy.last = self.iteration + round(self.config.densify.stop * steps)

    # ---- the end ----
    def finish(self) -> None:
        """Fit the time axis to the frames that came (frame i at i / N) and record the run's
        length, so that the run reads as an offline one; then every frame's final PSNR."""
        self.retime(len(self.scene.frames))
        self.config.train.iterations = self.iteration
        with torch.no_grad():
            for frame in self.scene.frames:
                output = render_frame(self.model, frame.camera, self._when(frame),
                                      self.background)
                self.records[frame.index].psnr_final = tissue_psnr(output.rgb, frame)


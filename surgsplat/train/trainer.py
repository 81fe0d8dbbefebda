"""The training loop: one random training frame per step, the method's components and weighted
loss terms, densification by a Strategy object, atomic checkpoints, resume, and a checkpoint on
Ctrl-C. The loop knows components only through their contract (`surgsplat.model.component`).

A run folder holds config.json (the resolved MethodConfig), scene.txt (the scene path),
scene.json (what identifies the scene: path, content fingerprint, frame count and size),
checkpoints/latest.pt, and train_log.jsonl (one JSON line per logged step, with every loss term;
iterations strictly increasing, none past the checkpoint once a run resumes). A checkpoint never
holds a value that is not finite: a step whose loss is not finite, or a save of such a model,
stops the run with TrainingDiverged and leaves the last good checkpoint in place.
"""

from __future__ import annotations

import json
import math
import resource
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from surgsplat.atomic import write_text_atomic
from surgsplat.data.scene import MIN_SIZE, Frame, Scene
from surgsplat.data.tool_masks import offset_tool_masks
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.methods.config import MethodConfig, to_dict
from surgsplat.methods.ranges import check_config
from surgsplat.methods.settings import LossWeight
from surgsplat.model.capabilities import PointSource
from surgsplat.model.component import (Component, FrameTime, ParamGroup, RenderContext,
                                       SceneInfo, SetupContext, providers)
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GEOMETRY_KEYS, GaussianModel
from surgsplat.model.init_points import initial_points
from surgsplat.render.rasterize import NonFiniteError
from surgsplat.render.render import RenderOutput
from surgsplat.train.checkpoint import (RESUME_ENTRIES, build_components,
                                        load_latest_or_previous, model_from_state, model_state,
                                        optimizer_state_in_order, save_atomic)
from surgsplat.train.strategy import build_strategy

CONFIG_FILE = "config.json"
SCENE_FILE = "scene.txt"
SCENE_ID_FILE = "scene.json"
CHECKPOINT = "checkpoints/latest.pt"
LOG_FILE = "train_log.jsonl"
LOG_EVERY = 10
PREFETCH_FRAMES = 3
"""Training frames decoded ahead in the background: the next ones of the sampling order."""
BUDGET_WINDOW = 50
"""Steps whose mean time a run trained to a time budget plans its remaining steps with."""


class TrainingDiverged(SurgsplatError):
    """A loss term or a trained value stopped being finite; nothing of it was saved."""


@dataclass
class StepStats:
    """What one training step reports."""

    iteration: int
    loss: float
    psnr: float  # over tissue pixels of the training frame
    num_gaussians: int
    seconds: float  # wall time since training started (this process plus resumed runs)
    terms: dict[str, float] = field(default_factory=dict)  # unweighted value of each loss term


def current_peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def psnr_from_mse(mse: float) -> float:
    return -10.0 * math.log10(max(mse, 1e-12))


def tissue_psnr(rgb: Tensor, frame: Frame) -> float:
    """PSNR (dB) of a render rgb [H, W, 3] against `frame` over its tissue pixels and the
    channels (the training frame's PSNR of a step; a frame without tissue gives 120 dB)."""
    squared = (rgb - frame.image).square_().mul_(frame.tissue.unsqueeze(-1))
    count = int(frame.tissue.sum()) * rgb.shape[2]
    return psnr_from_mse(float(squared.sum()) / max(count, 1))


def scene_info(scene: Scene) -> SceneInfo:
    """What components may know of `scene`."""
    first = scene.frames[0]
    return SceneInfo(num_frames=len(scene.frames), width=first.image.shape[1],
                     height=first.image.shape[0],
                     train_indices=tuple(frame.index for frame in scene.train_frames))


def scene_identity(scene: Scene) -> dict:
    """What tells `scene` apart from another: its path, content fingerprint, frame count and
    size (pixels); saved in a run folder and in metrics.json."""
    return {"path": str(scene.root.resolve()), "fingerprint": scene.fingerprint,
            "frames": len(scene.frames), "width": scene.width, "height": scene.height}


def check_loss_weights(weights: dict[str, LossWeight], declared: dict[str, str]) -> None:
    """Every declared term has a weight, and every nonzero weight names a declared term (a zero
    weight may name a term no component computes, so that `--set losses.NAME.weight=0` turns
    off the loss of a component that another `--set` replaced)."""
    unknown = sorted(name for name, weight in weights.items()
                     if name not in declared and weight.weight > 0)
    if unknown:
        raise SurgsplatError(f"losses.{unknown[0]}: no component of this method computes a loss "
                             f"term {unknown[0]!r}; terms: {', '.join(sorted(declared))}")
    missing = sorted(set(declared) - set(weights))
    if missing:
        raise SurgsplatError(f"losses.{missing[0]}: component {declared[missing[0]]!r} computes "
                             f"this term but the method gives it no weight")


def add_component_points(context: SetupContext, colors: Tensor,
                         components) -> tuple[Tensor, Tensor]:
    """Append the initial points of every component that is a `PointSource` to
    `context.points` (recording each one's rows in `context.added`); returns the means [M', 3]
    and colours [M', 3] of all initial points."""
    means = context.points
    for component in providers(components, PointSource):
        extra = component.initial_points(context)
        if extra is None or extra.means.shape[0] == 0:
            continue
        start = means.shape[0]
        means = torch.cat([means, extra.means.to(means)])
        colors = torch.cat([colors, extra.colors.to(colors)])
        context.added[id(component)] = slice(start, means.shape[0])
        context.points = means
    return means, colors


def declared_per_gaussian(context: SetupContext, components: dict[str, Component]
                          ) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Every component's initial per-Gaussian attributes, name -> [M, ...] each, split into the
    learnt ones (those its `attribute_lrs` names) and the others (buffers); SurgsplatError when
    two components (or the Gaussians themselves) own a name."""
    owners = {key: "the Gaussians" for key in GEOMETRY_KEYS}
    attributes: dict[str, Tensor] = {}
    buffers: dict[str, Tensor] = {}
    for name, component in components.items():
        learnt = component.attribute_lrs()
        for key, value in component.initial_attributes(context).items():
            if key in owners:
                raise SurgsplatError(f"component {name!r} declares the per-Gaussian attribute "
                                     f"{key!r}, already owned by {owners[key]}")
            owners[key] = f"component {name!r}"
            (attributes if key in learnt else buffers)[key] = value
    return attributes, buffers


def read_log(path: Path) -> list[dict]:
    """The entries of a training log (RUN/train_log.jsonl), in order: every line that is a JSON
    object with an integer "iteration" greater than the previous entry's. Lines that are not
    (one cut by a kill, bytes that are not UTF-8, another JSON value, an entry without an
    iteration or out of order) are skipped; no file gives no entries."""
    if not path.is_file():
        return []
    entries: list[dict] = []
    for raw in path.read_bytes().splitlines():
        try:
            entry = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            continue
        if isinstance(entry, dict) and type(entry.get("iteration")) is int \
                and (not entries or entry["iteration"] > entries[-1]["iteration"]):
            entries.append(entry)
    return entries


def trim_log(path: Path, iteration: int) -> None:
    """Cut the training log back to its entries (`read_log`) up to `iteration` (an atomic
    rewrite), so that after a kill, a stop or a resume it holds each iteration at most once, in
    increasing order, and nothing past the checkpoint the run continues from."""
    if not path.is_file():
        return
    kept = [entry for entry in read_log(path) if entry["iteration"] <= iteration]
    write_text_atomic(path, "".join(json.dumps(entry) + "\n" for entry in kept))


class Trainer:
    """Trains a method (a MethodConfig) on a scene into a run folder; SurgsplatError when the
    config breaks a declared range or rule between its fields (`check_config`)."""

    def __init__(self, config: MethodConfig, scene: Scene, run_dir: Path,
                 info: SceneInfo | None = None):
        """info: what the components are set up for; by default the scene's (`scene_info`),
        a stream's clip to come otherwise (`train.stream`)."""
        check_config(config)
        info = info or scene_info(scene)
        self.config = config.resolved(info)
        scene = offset_tool_masks(scene, self.config.train.tool_mask_offset_px)
        self.scene = scene
        self.run_dir = Path(run_dir)
        self.iteration = 0
        self.elapsed = 0.0
        self.peak_rss_mb = 0.0  # over this process and the runs it resumed
        torch.manual_seed(self.config.train.seed)
        points = initial_points(scene, self.config.init)
        centre = points.means.mean(dim=0)
        self.scene_extent = float((points.means - centre).norm(dim=1).max())
        components = build_components(self.config)
        context = SetupContext(scene=info, points=points.means, scene_extent=self.scene_extent,
                               frames=scene.train_frames)
        for component in components.values():
            component.setup(context)
        means, colors = add_component_points(context, points.colors, components.values())
        gaussians = GaussianModel.from_points(means, colors, self.config.gaussians,
                                              *declared_per_gaussian(context, components))
        self.model = SplatModel(gaussians, components)
        check_loss_weights(self.config.losses, self.model.loss_terms())
        factor = self.config.train.coarse_factor
        if factor > 1 and min(info.width, info.height) // factor < MIN_SIZE:
            raise SurgsplatError(f"train.coarse_factor: {factor} would downscale the "
                                 f"{info.width}x{info.height} frames under {MIN_SIZE}x{MIN_SIZE} "
                                 "pixels; use a smaller factor")
        self.optimizer, self.schedules = self._build_optimizer()
        budget = self.config.gaussians.cap(info.width, info.height)
        self.strategy = build_strategy(self.config.densify, self.scene_extent, budget,
                                       self.config.train.iterations)
        self.frame_generator = torch.Generator().manual_seed(self.config.train.seed)
        self._frame_queue: list[int] = []
        self._downscaled: dict[int, Frame] = {}  # frame index -> the frame at the current factor
        self._downscale_factor = 1
        self.background = torch.tensor(self.config.train.background, dtype=torch.float32)
        self.last_output: RenderOutput | None = None  # the latest step's render

    # ---- optimiser ----
    def _param_groups(self) -> list[ParamGroup]:
        """The canonical Gaussians' groups, one per per-Gaussian tensor (components' attributes
        included), then every component's own groups."""
        lr, extent = self.config.train.lr, self.scene_extent
        rates = {"means": (lr.means * extent, lr.means_final * extent),
                 "log_scales": (lr.log_scales, None), "quats": (lr.quats, None),
                 "opacity_logits": (lr.opacity_logits, None), "sh_dc": (lr.sh_dc, None),
                 "sh_rest": (lr.sh_rest, None)}
        rates.update({name: rate if isinstance(rate, tuple) else (rate, None)
                      for name, rate in self.model.attribute_lrs().items()})
        # every learnt per-Gaussian tensor has a rate: attributes without one are buffers
        groups = [ParamGroup(name, [param], *rates[name])
                  for name, param in self.model.gaussians.params.items()]
        return groups + self.model.component_param_groups()

    def _build_optimizer(self) -> tuple[torch.optim.Optimizer, dict[str, ParamGroup]]:
        groups = self._param_groups()
        names = [group.name for group in groups]
        if len(set(names)) != len(names):
            raise SurgsplatError(f"optimiser groups share names: {sorted(names)}")
        optimizer = torch.optim.Adam(
            [{"name": g.name, "params": g.params, "lr": g.lr} for g in groups],
            eps=1e-15, fused=True)
        return optimizer, {g.name: g for g in groups if g.lr_final is not None and g.lr > 0}

    def lr_progress(self) -> float:
        """Where the decaying learning rates are, from 0 (initial) to 1 (final): the fraction
        of the run done."""
        return min(self.iteration / max(self.config.train.iterations, 1), 1.0)

    def _update_learning_rates(self) -> None:
        progress = self.lr_progress()
        for group in self.optimizer.param_groups:
            schedule = self.schedules.get(group["name"])
            if schedule is not None:
                group["lr"] = schedule.lr * (schedule.lr_final / schedule.lr) ** progress

    # ---- one step ----
    def _next_frame(self) -> Frame:
        frames = self.scene.train_frames
        if not self._frame_queue:
            self._frame_queue = torch.randperm(len(frames), generator=self.frame_generator).tolist()
        frame = frames[self._frame_queue.pop()]
        for upcoming in reversed(self._frame_queue[-PREFETCH_FRAMES:]):
            frames[upcoming].prefetch()
        return frame

    def downscale_factor(self) -> int:
        """The factor this step's frame is downscaled by (`TrainConfig.downscale_at`)."""
        return self.config.train.downscale_at(self.iteration)

    def _at_step_size(self, frame: Frame) -> Frame:
        """`frame` at this step's size (`downscale_factor`); the downscaled frames of one
        factor are kept until the factor changes."""
        factor = self.downscale_factor()
        if factor != self._downscale_factor:
            self._downscaled.clear()
            self._downscale_factor = factor
        if factor == 1:
            return frame
        if frame.index not in self._downscaled:
            self._downscaled[frame.index] = frame.downscaled(factor)
        return self._downscaled[frame.index]

    def step(self) -> StepStats:
        """One optimisation step on one random training frame (downscaled in the run's coarse
        stages)."""
        started = time.perf_counter()
        self.iteration += 1
        self._update_learning_rates()
        frame = self._at_step_size(self._next_frame())
        iterations = self.config.train.iterations
        weights = {name: w.weight for name, w in self.config.losses.items()
                   if w.active_at(self.iteration, iterations)}
        when = FrameTime(frame.index, frame.time, losses=frozenset(weights),
                         tool_pixels=frame.tool)
        camera = self.model.camera_at(frame.camera, when)
        # densification's statistics come from full-size steps only: a coarse step's screen
        # gradients and radii are of blocks, not of the pixels the thresholds are set for
        densifying = (self.strategy.gathers_statistics(self.iteration)
                      and self._downscale_factor == 1)
        absgrad = torch.zeros(self.model.gaussians.num_gaussians) if densifying else None
        try:
            output, state = self.model.render(camera, when, self.background, absgrad=absgrad)
        except NonFiniteError as err:
            raise TrainingDiverged(f"training diverged at iteration {self.iteration}: {err}"
                                   ) from None
        context = RenderContext(frame=frame, when=when, camera=camera, output=output,
                                state=state, gaussians=self.model.gaussians,
                                iteration=self.iteration)
        terms = self.model.losses(context, when.losses)
        loss = sum(weights[name] * value for name, value in terms.items())
        if not math.isfinite(float(loss.detach())):
            bad = [name for name, value in terms.items() if not bool(torch.isfinite(value).all())]
            raise TrainingDiverged(f"training diverged at iteration {self.iteration}: loss "
                                   f"term{'s' if len(bad) > 1 else ''} {', '.join(bad)} not finite")
        self.optimizer.zero_grad(set_to_none=True)
        if loss.requires_grad:  # not when every active term is a constant 0 on this frame
            loss.backward()
        if densifying:  # from this step's state, before the optimiser moves it
            densify_weights = self.model.densify_weights(context)
        self.optimizer.step()
        if densifying:
            self.strategy.step_post_backward(self.iteration, self.model.gaussians,
                                             self.optimizer, absgrad,
                                             max(camera.width, camera.height),
                                             output.projection.radii.detach(), densify_weights,
                                             self.model.opacity_factor)
        self.model.after_step(self.iteration)
        self.last_output = output
        self.elapsed += time.perf_counter() - started
        with torch.no_grad():
            psnr = tissue_psnr(output.rgb, frame)
        return StepStats(self.iteration, float(loss.detach()), psnr,
                         self.model.gaussians.num_gaussians, self.elapsed,
                         {name: float(value.detach()) for name, value in terms.items()})

    # ---- a time budget ----
    def plan_to_budget(self, recent_step_seconds: Sequence[float]) -> None:
        """With train.budget_seconds, set train.iterations (and the densification schedule) to
        the steps done plus the steps the rest of the budget holds at the mean time of
        `recent_step_seconds`: the run ends at the budget with every stage of its schedule, as
        fractions of the run, re-referred to the new length. Nothing without a budget."""
        train = self.config.train
        if train.budget_seconds <= 0 or not recent_step_seconds:
            return
        seconds_per_step = sum(recent_step_seconds) / len(recent_step_seconds)
        remaining = max(train.budget_seconds - self.elapsed, 0.0)
        planned = self.iteration + int(remaining / seconds_per_step)
        if planned != train.iterations:
            train.iterations = planned
            self.strategy.reschedule(planned)

    # ---- the run ----
    def fit(self, on_step: Callable[[StepStats], None] | None = None) -> None:
        """Train to config.train.iterations; Ctrl-C saves a checkpoint and re-raises; a loss or a
        value that stops being finite raises TrainingDiverged, saying which checkpoint is kept."""
        self.write_run_files()
        trim_log(self.run_dir / LOG_FILE, self.iteration)
        log = open(self.run_dir / LOG_FILE, "a", buffering=1)  # line-buffered: a crash keeps the log
        train = self.config.train
        last_save, saved_at = time.monotonic(), self.iteration
        recent: deque[float] = deque(maxlen=BUDGET_WINDOW)  # seconds of the latest steps
        try:
            with stops_between_steps() as stop_requested:
                while self.iteration < train.iterations:
                    before = self.elapsed
                    stats = self.step()
                    recent.append(self.elapsed - before)
                    self.plan_to_budget(recent)
                    if on_step:
                        on_step(stats)
                    if stats.iteration % LOG_EVERY == 0 or stats.iteration == train.iterations:
                        log.write(json.dumps(asdict(stats)) + "\n")
                    if (stats.iteration % train.checkpoint_every == 0
                            or time.monotonic() - last_save >= train.checkpoint_seconds):
                        self.save()
                        last_save, saved_at = time.monotonic(), self.iteration
                    if stop_requested():
                        raise KeyboardInterrupt
            if saved_at != self.iteration or not (self.run_dir / CHECKPOINT).is_file():
                self.save()
            if train.budget_seconds > 0:  # config.json says how long the run turned out
                self.write_run_files()
        except KeyboardInterrupt:
            self.save()
            raise
        except TrainingDiverged as err:
            kept = (f"{self.run_dir / CHECKPOINT} (iteration {saved_at}) is kept"
                    if (self.run_dir / CHECKPOINT).is_file() else "no checkpoint was written")
            raise TrainingDiverged(f"{err}; {kept}. A resume repeats the same steps: start a "
                                   "new run with lower learning rates or loss weights (--set)"
                                   ) from None
        finally:
            log.close()

    def write_run_files(self) -> None:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.run_dir / CONFIG_FILE, json.dumps(to_dict(self.config), indent=2) + "\n")
        write_text_atomic(self.run_dir / SCENE_FILE, str(self.scene.root.resolve()) + "\n")
        write_text_atomic(self.run_dir / SCENE_ID_FILE,
                          json.dumps(scene_identity(self.scene), indent=2) + "\n")

    # ---- checkpoints ----
    def state_dict(self) -> dict:
        self.peak_rss_mb = max(self.peak_rss_mb, current_peak_rss_mb())
        return {
            **model_state(self.config, self.model),
            "num_frames": len(self.scene.frames),
            "peak_rss_mb": self.peak_rss_mb,
            "iteration": self.iteration,
            "elapsed_seconds": self.elapsed,
            "optimizer": self.optimizer.state_dict(),
            "strategy": self.strategy.state_dict(),
            "scene_extent": self.scene_extent,
            "frame_generator": self.frame_generator.get_state(),
            "frame_queue": list(self._frame_queue),
            "torch_rng": torch.get_rng_state(),
        }

    def save(self) -> Path:
        """Write the checkpoint atomically; TrainingDiverged instead when a trained value is not
        finite, so the checkpoint on disk stays the last good one."""
        for group in self.optimizer.param_groups:
            if not all(bool(torch.isfinite(param).all()) for param in group["params"]):
                raise TrainingDiverged(f"training diverged at iteration {self.iteration}: "
                                       f"{group['name']} holds values that are not finite")
        path = self.run_dir / CHECKPOINT
        save_atomic(self.state_dict(), path)
        return path

    def load(self, path: Path) -> DataError | None:
        """Restore a checkpoint of this run (model, components, optimiser, strategy, sampling):
        the one at `path`, or the one kept before it when `path` is damaged, in which case the
        error about `path` is returned."""
        state, path, damaged = load_latest_or_previous(path, RESUME_ENTRIES)
        self.model = model_from_state(self.config, state, path)
        self.scene_extent = float(state["scene_extent"])
        self.optimizer, self.schedules = self._build_optimizer()
        names = [group["name"] for group in self.optimizer.param_groups]
        self.optimizer.load_state_dict(optimizer_state_in_order(state["optimizer"], names, path))
        self.strategy.load_state_dict(state["strategy"])
        self.frame_generator.set_state(state["frame_generator"])
        self._frame_queue = list(state["frame_queue"])
        torch.set_rng_state(state["torch_rng"])
        self.iteration = int(state["iteration"])
        self.elapsed = float(state["elapsed_seconds"])
        self.peak_rss_mb = float(state["peak_rss_mb"])
        return damaged


@contextmanager
def stops_between_steps() -> Iterator[Callable[[], bool]]:
    """Hold Ctrl-C and SIGTERM until the current step ends: yields a function saying whether one
    came. A stop in the middle of a step (e.g. of densification, with some per-Gaussian tensors
    resized and others not) would leave a state no checkpoint can hold. Outside the main thread,
    where signal handlers cannot be set, stops act at once as before."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    pending: list[int] = []
    previous = {number: signal.signal(number, lambda got, frame: pending.append(got))
                for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield lambda: bool(pending)
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)

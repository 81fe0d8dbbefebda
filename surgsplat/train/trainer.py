"""The training loop: one random training frame per step, densification by a Strategy object,
atomic checkpoints, resume, and a checkpoint on Ctrl-C.

A run folder holds config.json (the resolved MethodConfig), scene.txt (the scene path),
checkpoints/latest.pt, and train_log.jsonl (one JSON line per logged step).
"""

from __future__ import annotations

import json
import math
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from surgsplat.data.scene import Frame, Scene
from surgsplat.losses.depth import depth_l1, inverse_depth_l1
from surgsplat.losses.photometric import photometric_loss
from surgsplat.methods.config import MethodConfig, to_dict
from surgsplat.model.dynamic import DeformableGaussians
from surgsplat.model.exposure import ExposureCurve
from surgsplat.model.gaussians import GaussianModel
from surgsplat.model.init_points import initial_points
from surgsplat.train.checkpoint import load_checkpoint, save_atomic
from surgsplat.train.strategy import DensifyStrategy

CONFIG_FILE = "config.json"
SCENE_FILE = "scene.txt"
CHECKPOINT = "checkpoints/latest.pt"
LOG_FILE = "train_log.jsonl"


@dataclass
class StepStats:
    """What one training step reports."""

    iteration: int
    loss: float
    psnr: float  # over tissue pixels of the training frame
    num_gaussians: int
    seconds: float  # wall time since training started (this process plus resumed runs)


def current_peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def psnr_from_mse(mse: float) -> float:
    return -10.0 * math.log10(max(mse, 1e-12))


class Trainer:
    """Trains a DeformableGaussians model on a scene into a run folder."""

    def __init__(self, config: MethodConfig, scene: Scene, run_dir: Path):
        num_frames = len(scene.frames)
        config.deformation = config.deformation.for_frames(num_frames)
        config.exposure = config.exposure.for_frames(num_frames)
        budget = config.gaussians.cap(scene.camera.width, scene.camera.height)
        # start with at most half the budget, leaving room for densification
        config.init.max_points = min(config.init.max_points, budget // 2)
        self.config = config
        self.scene = scene
        self.run_dir = Path(run_dir)
        self.iteration = 0
        self.elapsed = 0.0
        self.peak_rss_mb = 0.0  # over this process and the runs it resumed
        torch.manual_seed(config.train.seed)
        points = initial_points(scene, config.init)
        field = config.deformation.build()
        field.set_bounds(points.means.min(dim=0).values, points.means.max(dim=0).values)
        gaussians = GaussianModel.from_points(
            points.means, points.colors, config.gaussians,
            field.per_gaussian_attributes(points.means.shape[0]))
        self.model = DeformableGaussians(gaussians, field, ExposureCurve(config.exposure))
        centre = points.means.mean(dim=0)
        self.scene_extent = float((points.means - centre).norm(dim=1).max())
        self.optimizer = self._build_optimizer()
        self.strategy = DensifyStrategy(config.densify, self.scene_extent, budget)
        self.frame_generator = torch.Generator().manual_seed(config.train.seed)
        self._frame_queue: list[int] = []
        self.background = torch.tensor(config.train.background, dtype=torch.float32)

    # ---- optimiser ----
    def _gaussian_lrs(self) -> dict[str, float]:
        lr = self.config.train.lr
        lrs = {"means": lr.means * self.scene_extent, "log_scales": lr.log_scales,
               "quats": lr.quats, "opacity_logits": lr.opacity_logits, "sh_dc": lr.sh_dc,
               "sh_rest": lr.sh_rest}
        lrs.update(self.model.field.attribute_lrs())
        return lrs

    def _build_optimizer(self) -> torch.optim.Optimizer:
        lrs = self._gaussian_lrs()
        params = self.model.gaussians.params
        groups = [{"name": name, "params": [params[name]], "lr": lrs[name]} for name in params]
        groups += self.model.field.param_groups()
        groups.append({"name": "exposure", "params": [self.model.exposure.log_gains],
                       "lr": self.config.exposure.lr})
        return torch.optim.Adam(groups, eps=1e-15, fused=True)

    def _update_learning_rates(self) -> None:
        lr = self.config.train.lr
        progress = min(self.iteration / max(self.config.train.iterations, 1), 1.0)
        means_lr = lr.means * (lr.means_final / lr.means) ** progress * self.scene_extent
        for group in self.optimizer.param_groups:
            if group["name"] == "means":
                group["lr"] = means_lr

    # ---- one step ----
    def _next_frame(self) -> Frame:
        frames = self.scene.train_frames
        if not self._frame_queue:
            self._frame_queue = torch.randperm(len(frames), generator=self.frame_generator).tolist()
        return frames[self._frame_queue.pop()]

    def step(self) -> StepStats:
        """One optimisation step on one random training frame."""
        started = time.perf_counter()
        self.iteration += 1
        self._update_learning_rates()
        frame = self._next_frame()
        absgrad = torch.zeros(self.model.gaussians.num_gaussians)
        out = self.model.render(self.scene.camera, frame.time, self.background, absgrad=absgrad)
        loss, mse = self._loss(out, frame)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        camera = self.scene.camera
        screen_grad = absgrad * (0.5 * max(camera.width, camera.height))
        self.optimizer.step()
        self.strategy.step_post_backward(self.iteration, self.model.gaussians, self.optimizer,
                                         screen_grad, out.projection.radii.detach())
        self.elapsed += time.perf_counter() - started
        return StepStats(self.iteration, loss.item(), psnr_from_mse(mse),
                         self.model.gaussians.num_gaussians, self.elapsed)

    def _loss(self, out, frame: Frame) -> tuple[Tensor, float]:
        config = self.config.train
        tissue = frame.tissue
        loss = photometric_loss(out.rgb, frame.image, tissue, lambda_dssim=config.lambda_dssim)
        if frame.depth is not None and config.lambda_depth > 0:
            depth_fn = depth_l1 if config.depth_loss == "l1" else inverse_depth_l1
            loss = loss + config.lambda_depth * depth_fn(out.depth, frame.depth, tissue)
        for name, value in self.model.field.regularisation().items():
            weight = config.regularisation.get(name, 0.0)
            if weight:
                loss = loss + weight * value
        with torch.no_grad():
            mse = float(((out.rgb - frame.image)[tissue] ** 2).mean())
        return loss, mse

    # ---- the run ----
    def fit(self, on_step: Callable[[StepStats], None] | None = None) -> None:
        """Train to config.train.iterations; Ctrl-C saves a checkpoint and re-raises."""
        self.write_run_files()
        log = open(self.run_dir / LOG_FILE, "a", buffering=1)  # line-buffered: a crash keeps the log
        try:
            while self.iteration < self.config.train.iterations:
                stats = self.step()
                if on_step:
                    on_step(stats)
                if stats.iteration % 10 == 0 or stats.iteration == self.config.train.iterations:
                    log.write(json.dumps(stats.__dict__) + "\n")
                if stats.iteration % self.config.train.checkpoint_every == 0:
                    self.save()
        except KeyboardInterrupt:
            self.save()
            raise
        finally:
            log.close()
        self.save()

    def write_run_files(self) -> None:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / CONFIG_FILE).write_text(json.dumps(to_dict(self.config), indent=2) + "\n")
        (self.run_dir / SCENE_FILE).write_text(str(self.scene.root.resolve()) + "\n")

    # ---- checkpoints ----
    def state_dict(self) -> dict:
        self.peak_rss_mb = max(self.peak_rss_mb, current_peak_rss_mb())
        return {
            "peak_rss_mb": self.peak_rss_mb,
            "iteration": self.iteration,
            "elapsed_seconds": self.elapsed,
            "gaussians": {k: v.detach() for k, v in self.model.gaussians.params.items()},
            "sh_degree": self.model.gaussians.sh_degree,
            "field": self.model.field.state_dict(),
            "exposure": self.model.exposure.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "strategy": self.strategy.state_dict(),
            "scene_extent": self.scene_extent,
            "frame_generator": self.frame_generator.get_state(),
            "frame_queue": list(self._frame_queue),
            "torch_rng": torch.get_rng_state(),
        }

    def save(self) -> Path:
        path = self.run_dir / CHECKPOINT
        save_atomic(self.state_dict(), path)
        return path

    def load(self, path: Path) -> None:
        """Restore a checkpoint of this run (model, field, optimiser, strategy, sampling)."""
        state = load_checkpoint(path)
        gaussians = GaussianModel(state["gaussians"], state["sh_degree"])
        self.model = DeformableGaussians(gaussians, self.model.field, self.model.exposure)
        self.model.field.load_state_dict(state["field"])
        self.model.exposure.load_state_dict(state["exposure"])
        self.scene_extent = float(state["scene_extent"])
        self.optimizer = self._build_optimizer()
        self.optimizer.load_state_dict(state["optimizer"])
        self.strategy.load_state_dict(state["strategy"])
        self.frame_generator.set_state(state["frame_generator"])
        self._frame_queue = list(state["frame_queue"])
        torch.set_rng_state(state["torch_rng"])
        self.iteration = int(state["iteration"])
        self.elapsed = float(state["elapsed_seconds"])
        self.peak_rss_mb = float(state["peak_rss_mb"])

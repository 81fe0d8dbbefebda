"""`surgsplat train`: fit a method to a scene, with resume and a checkpoint on Ctrl-C."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import TextColumn

from surgsplat.cli.progress import progress_bar
from surgsplat.data.scene import load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.train.run import read_run_config, read_run_scene
from surgsplat.train.trainer import CHECKPOINT, StepStats, Trainer


def train_run(config: MethodConfig, data: Path | None, out: Path, resume: bool,
              iterations: int | None = None) -> Trainer:
    """Build (or resume) a Trainer and run it to the end with a progress bar.

    On resume the run's saved config is used (`config` only names the method), with
    `iterations` replacing its length when given.
    """
    console = Console()
    checkpoint = out / CHECKPOINT
    if resume:
        if not checkpoint.is_file():
            raise SurgsplatError(f"{checkpoint}: nothing to resume (no checkpoint in {out})")
        config = read_run_config(out)
        scene = read_run_scene(out, data)
    else:
        if data is None:
            raise SurgsplatError("--data is required unless --resume continues a run")
        if checkpoint.is_file():
            raise SurgsplatError(f"{out} already holds a run; pass --resume to continue it or "
                                 "choose another --out")
        scene = load_scene(data)
    if iterations is not None:
        if iterations <= 0:
            raise SurgsplatError(f"--iters must be positive, got {iterations}")
        config.train.iterations = iterations
    trainer = Trainer(config, scene, out)
    if resume:
        trainer.load(checkpoint)
        console.print(f"resuming {out} at iteration {trainer.iteration}")
    with progress_bar(TextColumn("loss {task.fields[loss]:.4f}"),
                      TextColumn("PSNR {task.fields[psnr]:.2f}"),
                      TextColumn("{task.fields[gaussians]} Gaussians")) as bar:
        task = bar.add_task(f"train {config.name}", total=config.train.iterations,
                            completed=trainer.iteration, loss=0.0, psnr=0.0, gaussians=0)

        def report(stats: StepStats) -> None:
            bar.update(task, completed=stats.iteration, loss=stats.loss, psnr=stats.psnr,
                       gaussians=stats.num_gaussians)

        try:
            trainer.fit(report)
        except KeyboardInterrupt:
            raise SurgsplatError(f"interrupted at iteration {trainer.iteration}; checkpoint saved "
                                 f"to {checkpoint}; continue with --resume") from None
    console.print(f"trained {trainer.iteration} iterations in {trainer.elapsed:.0f} s; "
                  f"{trainer.model.gaussians.num_gaussians} Gaussians; run folder: {out}")
    return trainer


def train_command(
    method: Annotated[str, typer.Option(help=f"Method preset: {', '.join(PRESETS)}.")] = "deform3dgs",
    data: Annotated[Path | None, typer.Option(help="EndoNeRF-layout scene folder.")] = None,
    out: Annotated[Path, typer.Option(help="Run folder to write.")] = Path("runs/latest"),
    iters: Annotated[int | None, typer.Option(help="Number of iterations (preset default if "
                                                     "omitted).")] = None,
    resume: Annotated[bool, typer.Option(help="Continue the run in --out from its checkpoint.")] = False,
) -> None:
    """Train a deforming-Gaussian reconstruction of a scene."""
    train_run(method_config(method), data, out, resume, iters)

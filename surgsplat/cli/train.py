"""`surgsplat train`: fit a method to a scene, with resume and a checkpoint on Ctrl-C."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import TextColumn

from surgsplat.cli.progress import progress_bar
from surgsplat.errors import SurgsplatError
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.overrides import build_method_config, dotted_keys, parse_assignment
from surgsplat.methods.registry import DEFAULT_PRESET, PRESETS
from surgsplat.pipeline.train import after_training, check_new_run_folder, fit, start_training
from surgsplat.train.checkpoint import has_checkpoint
from surgsplat.train.run import LOCK_FILE, read_run_config, run_lock
from surgsplat.train.trainer import CHECKPOINT, StepStats, Trainer


def train_with_progress(config: MethodConfig, data: Path | None, out: Path, resume: bool,
                        iterations: int | None = None) -> Trainer:
    """`pipeline.train.train_run` with a progress bar and its notes printed."""
    console = Console()

    def note(text: str) -> None:
        console.print(text, markup=False, highlight=False)

    trainer = start_training(config, data, out, resume, iterations, note)
    if resume:
        console.print(f"resuming {out} at iteration {trainer.iteration}")
    with progress_bar(TextColumn("loss {task.fields[loss]:.4f}"),
                      TextColumn("PSNR {task.fields[psnr]:.2f}"),
                      TextColumn("{task.fields[gaussians]} Gaussians")) as bar:
        task = bar.add_task(f"train {trainer.config.name}",
                            total=trainer.config.train.iterations, completed=trainer.iteration,
                            loss=0.0, psnr=0.0, gaussians=0)

        def report(stats: StepStats) -> None:  # a budgeted run re-plans its length
            bar.update(task, completed=stats.iteration, total=trainer.config.train.iterations,
                       loss=stats.loss, psnr=stats.psnr, gaussians=stats.num_gaussians)

        fit(trainer, report)
    console.print(f"trained {trainer.iteration} iterations in {trainer.elapsed:.0f} s; "
                  f"{trainer.model.gaussians.num_gaussians} Gaussians; run folder: {out}")
    after_training(trainer, data, note)
    return trainer


RUN_LENGTH_KEYS = {"train.iterations", "train.budget_seconds"}
"""The settings that give a run's length, as --iters and --budget do."""


def check_length_given_once(iters: int | None, budget: float | None,
                            assignments: list[str]) -> None:
    """SurgsplatError naming both when --iters or --budget gives the run's length and another
    of them, or a `--set` of RUN_LENGTH_KEYS, gives it too (several `--set`s apply in order)."""
    options = [f"{name} {value:g}" for name, value in (("--iters", iters), ("--budget", budget))
               if value is not None]
    given = options + [f"--set {text}" for text in assignments
                       if dotted_keys(parse_assignment(text)) & RUN_LENGTH_KEYS]
    if options and len(given) > 1:
        raise SurgsplatError(f"{given[0]} and {given[1]} each set the run's length: give one")


@contextmanager
def new_run_folder(out: Path) -> Iterator[None]:
    """Own `out` (`run_lock`, creating it) for a new run while the block runs, once sure that it
    may receive one (`check_new_run_folder`). The folder is checked with the lock held, so that
    a run started there at the same instant is reported as the lock's holder rather than as
    files of the user's; and before, unless it holds a lock file already, so that no lock file
    is left in a folder of the user's."""
    if not (out / LOCK_FILE).exists():
        check_new_run_folder(out)
    with run_lock(out, create=True):
        if any(entry.name != LOCK_FILE for entry in out.iterdir()):
            check_new_run_folder(out)
        yield


def train_command(
    method: Annotated[str | None, typer.Option(
        help=f"Method preset: {', '.join(PRESETS)} (default {DEFAULT_PRESET}; see `surgsplat "
             f"methods`).")] = None,
    data: Annotated[Path | None, typer.Option(help="EndoNeRF-layout scene folder.")] = None,
    out: Annotated[Path, typer.Option(help="Run folder to write.")] = Path("runs/latest"),
    iters: Annotated[int | None, typer.Option(help="Number of iterations (train.iterations; "
                                                     "the preset's or --config file's if "
                                                     "omitted).")] = None,
    budget: Annotated[float | None, typer.Option(
        help="Train for this many seconds instead of a number of iterations: the schedule is "
             "scaled to fit, so every stage still runs (train.budget_seconds).",
        min=0.001)] = None,
    resume: Annotated[bool, typer.Option(help="Continue the run in --out from its checkpoint.")] = False,
    config: Annotated[Path | None, typer.Option(
        "--config", help="JSON or TOML file of settings, e.g. a run's config.json to reproduce "
                         "it.")] = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Change one setting, e.g. --set losses.normal.weight=0.1 --set "
                      "train.iterations=5000 (repeatable; applied after --config).")] = None,
) -> None:
    """Train a deforming-Gaussian reconstruction of a scene."""
    if resume:
        if config is not None or set_ or budget is not None:
            raise SurgsplatError("--config, --set and --budget change a new run; a resumed run "
                                 "keeps its saved config (only --iters may extend it)")
        if not out.is_dir():
            raise SurgsplatError(f"{out / CHECKPOINT}: nothing to resume (no run folder {out})")
        with run_lock(out):
            if not has_checkpoint(out / CHECKPOINT):
                raise SurgsplatError(f"{out / CHECKPOINT}: nothing to resume (no checkpoint in "
                                     f"{out})")
            saved = read_run_config(out)
            if method is not None and method != saved.name:
                raise SurgsplatError(f"{out} holds a {saved.name!r} run; --method {method} does "
                                     "not apply to it")
            train_with_progress(saved, data, out, resume, iters)
        return
    check_length_given_once(iters, budget, set_ or [])
    new_config = build_method_config(method, config, set_ or [])
    if budget is not None:
        new_config.train.budget_seconds = budget
    if data is None:
        raise SurgsplatError("--data is required unless --resume continues a run")
    with new_run_folder(out):
        train_with_progress(new_config, data, out, resume, iters)

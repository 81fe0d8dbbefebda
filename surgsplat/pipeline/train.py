"""Train a method on a scene into a run folder, or resume its run: build (or load) the Trainer,
fit it, then make the run's products (pipeline/products.py: e.g. the tool's articulation).

`train_run` does all three; a caller that shows progress calls `start_training`, `fit` and
`after_training` itself. Lines for the user go to a `note` callback."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from surgsplat.data.scene import load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.overrides import apply_values
from surgsplat.pipeline.products import products_of
from surgsplat.pipeline.run_folders import check_output_folder
from surgsplat.train.checkpoint import has_checkpoint, previous_path
from surgsplat.train.run import load_trained_run, read_run_config, read_run_scene
from surgsplat.train.trainer import CHECKPOINT, CONFIG_FILE, SCENE_FILE, StepStats, Trainer

Note = Callable[[str], None]
"""Receives a line for the user (a warning or a summary)."""


def quiet(text: str) -> None:
    """A `Note` that drops the line."""


def check_new_run_folder(out: Path) -> None:
    """SurgsplatError unless `out` may receive a new run: absent, an empty folder, or a run
    folder (its config.json and scene.txt present; one holding a checkpoint is then refused
    with a hint to --resume). Any other folder holds a user's files that the run would
    replace."""
    check_output_folder(out, "--out", "a run writes config.json, scene.json, ...",
                        identifying=(CONFIG_FILE, SCENE_FILE), kind="a surgsplat run folder")


def start_training(config: MethodConfig, data: Path | None, out: Path, resume: bool,
                   iterations: int | None = None, note: Note = quiet) -> Trainer:
    """A Trainer of a new run in `out`, or of the run there resumed from its checkpoint.

    On resume the run's saved config is used (`config` only names the method), with
    `iterations` replacing its length when given.
    """
    checkpoint = out / CHECKPOINT
    if resume:
        if not has_checkpoint(checkpoint):
            raise SurgsplatError(f"{checkpoint}: nothing to resume (no checkpoint in {out})")
        config = read_run_config(out)
        scene = read_run_scene(out, data)
    else:
        if data is None:
            raise SurgsplatError("--data is required unless --resume continues a run")
        if has_checkpoint(checkpoint):
            raise SurgsplatError(f"{out} already holds a run; pass --resume to continue it or "
                                 "choose another --out")
        scene = load_scene(data)
    if iterations is not None:
        if iterations <= 0:
            raise SurgsplatError(f"--iters must be positive, got {iterations}")
        config = apply_values(config, {"train": {"iterations": iterations}}, where="--iters")
    trainer = Trainer(config, scene, out)
    if resume:
        damaged = trainer.load(checkpoint)
        if damaged is not None:
            note(f"{damaged}; continuing from the checkpoint kept before it, "
                 f"{previous_path(checkpoint)}")
        if trainer.iteration > trainer.config.train.iterations:
            raise SurgsplatError(f"{out} is at iteration {trainer.iteration}, past --iters "
                                 f"{trainer.config.train.iterations}; a run cannot be shortened")
    return trainer


def fit(trainer: Trainer, on_step: Callable[[StepStats], None] | None = None) -> None:
    """Train to the end (`on_step` after every step); Ctrl-C leaves a checkpoint and a
    SurgsplatError saying how to continue."""
    try:
        trainer.fit(on_step)
    except KeyboardInterrupt:
        raise SurgsplatError(f"interrupted at iteration {trainer.iteration}; checkpoint saved "
                             f"to {trainer.run_dir / CHECKPOINT}; continue with --resume") \
            from None


def after_training(trainer: Trainer, data: Path | None, note: Note = quiet) -> None:
    """Make the products the run's components call for (`products_of`), each noted in one line,
    or why it could not be made."""
    products = products_of(trainer.model)
    if not products:
        return
    run = load_trained_run(trainer.run_dir, data)
    for product in products:
        try:
            note(product.make(run))
        except SurgsplatError as err:
            note(f"no {product.name}: {err}")


def train_run(config: MethodConfig, data: Path | None, out: Path, resume: bool,
              iterations: int | None = None, on_step: Callable[[StepStats], None] | None = None,
              note: Note = quiet) -> Trainer:
    """Build (or resume) a Trainer, run it to the end, make its products; see the functions it
    calls."""
    trainer = start_training(config, data, out, resume, iterations, note)
    fit(trainer, on_step)
    after_training(trainer, data, note)
    return trainer

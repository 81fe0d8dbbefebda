"""`surgsplat eval RUN`: metrics over the test frames, printed and written to RUN/metrics.json."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from surgsplat.atomic import check_writable
from surgsplat.cli.progress import progress_bar
from surgsplat.errors import SurgsplatError
from surgsplat.eval.run_metrics import METRICS_FILE, EvalOptions
from surgsplat.pipeline.evaluate import evaluate
from surgsplat.pipeline.run_folders import load_run
from surgsplat.train.run import run_lock


def print_metrics(metrics: dict, console: Console) -> None:
    table = Table(title=f"{metrics.get('evaluated_on', 'test')}-frame metrics", show_header=True)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key, value in metrics.items():
        if isinstance(value, dict):  # conventions, scene
            continue
        if isinstance(value, float):
            text = f"{value:.4f}" if abs(value) < 10 else f"{value:.2f}"
        else:
            text = "null" if value is None else str(value)
        table.add_row(key, text)
    console.print(table)


def print_coverage(metrics: dict, console: Console) -> None:
    """One line naming the metric families that cover fewer than all test frames, if any."""
    total = metrics["test_frames"]
    fewer = [f"{family} {count}" for family, count in metrics["frames_covered"].items()
             if count < total]
    if fewer:
        console.print(f"over fewer than the {total} test frames: {', '.join(fewer)} "
                      f"(frames_covered in {METRICS_FILE})", highlight=False)


def evaluate_and_report(run_dir: Path, options: EvalOptions | None = None,
                        data: Path | None = None) -> dict:
    """Evaluate the run with a progress bar (`pipeline.evaluate.evaluate`: writes
    RUN/metrics.json), print the table; returns the metrics."""
    run = load_run(run_dir, data)
    with progress_bar() as bar:
        task = bar.add_task("evaluate", total=len((options or EvalOptions()).frames_of(run)))
        metrics = evaluate(run, options, lambda done, _: bar.update(task, completed=done))
    console = Console()
    print_metrics(metrics, console)
    print_coverage(metrics, console)
    console.print(f"written: {Path(run_dir) / METRICS_FILE}")
    return metrics


def eval_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
    alexnet_weights: Annotated[Path | None, typer.Option(
        help="torchvision AlexNet checkpoint for LPIPS (else $SURGSPLAT_ALEXNET_WEIGHTS or the "
             "torch hub cache; LPIPS is null when none is found).")] = None,
    geometry: Annotated[bool, typer.Option(help="Geometry against gt/ meshes (phantoms).")] = True,
    frames: Annotated[str, typer.Option(
        help="Frames scored: test (held out, every 8th frame from 1) or train (the fit to the "
             "training frames, for a scene with no held-out frame such as one stereo pair; "
             "metrics.json says which).")] = "test",
) -> None:
    """Evaluate a trained run on its test frames (every 8th frame from 1)."""
    if frames not in ("test", "train"):
        raise SurgsplatError(f"--frames: expected test or train, got {frames!r}")
    with run_lock(run_dir):
        check_writable(run_dir / METRICS_FILE)  # before the evaluation, not after it
        evaluate_and_report(run_dir, EvalOptions(alexnet_weights=alexnet_weights,
                                                 geometry=geometry, frames=frames), data)

"""`surgsplat demo`: the whole pipeline on the built-in phantom, in a few minutes on a CPU."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.cli.eval_cmd import evaluate_and_report
from surgsplat.cli.info import print_summary_table
from surgsplat.cli.render_videos import write_videos_with_progress
from surgsplat.cli.train import train_with_progress
from surgsplat.data.phantom.generate import PhantomConfig, generate_phantom
from surgsplat.errors import SurgsplatError
from surgsplat.export.report import write_report
from surgsplat.methods.registry import DEFAULT_PRESET, PRESETS, method_config
from surgsplat.train.run import load_trained_run, read_run_config, run_lock
from surgsplat.train.trainer import CHECKPOINT

DEMO_ITERATIONS = 1500


def demo_command(
    out: Annotated[Path, typer.Option(help="Folder for the phantom and the run.")] = Path("demo"),
    method: Annotated[str, typer.Option(help=f"Method preset: {', '.join(PRESETS)}.")] =
        DEFAULT_PRESET,
    iters: Annotated[int, typer.Option(help="Training iterations.")] = DEMO_ITERATIONS,
) -> None:
    """Generate the small phantom, train, evaluate against its ground truth, render videos and
    write an HTML report."""
    scene_dir, run_dir = out / "phantom", out / "run"
    with run_lock(run_dir, create=True):
        _demo(scene_dir, run_dir, method, iters)


def _demo(scene_dir: Path, run_dir: Path, method: str, iters: int) -> None:
    console = Console()
    resume = (run_dir / CHECKPOINT).is_file()
    if resume:
        saved = read_run_config(run_dir)
        if (saved.name, saved.train.iterations) != (method, iters):
            raise SurgsplatError(f"{run_dir} holds a demo run of {saved.name} for "
                                 f"{saved.train.iterations} iterations, not {method} for {iters}; "
                                 f"choose another --out or delete {run_dir}")
    if not (scene_dir / "poses_bounds.npy").is_file():
        console.rule("1/4 phantom")
        generate_phantom(PhantomConfig(preset="small", motion="pulling"), scene_dir)
    print_summary_table(scene_dir)
    console.rule("2/4 train")
    train_with_progress(method_config(method), scene_dir, run_dir, resume=resume,
                        iterations=iters)
    console.rule("3/4 evaluate")
    evaluate_and_report(run_dir)
    console.rule("4/4 render and report")
    videos = write_videos_with_progress(load_trained_run(run_dir), run_dir / "videos", fps=10.0)
    report = write_report([run_dir], run_dir / "report.html")
    console.print(f"\nresults in {run_dir}: metrics.json, "
                  + ", ".join(str(v.relative_to(run_dir)) for v in videos))
    console.print(f"report: {report}")

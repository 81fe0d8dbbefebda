"""`surgsplat demo`: the whole pipeline on the built-in phantom, in a few minutes on a CPU."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.cli.eval_cmd import evaluate_and_report
from surgsplat.cli.info import print_summary_table
from surgsplat.cli.render_videos import write_run_videos
from surgsplat.cli.train import train_run
from surgsplat.data.phantom.generate import PhantomConfig, generate_phantom
from surgsplat.export.report import write_report
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.train.run import load_trained_run

DEMO_ITERATIONS = 1500


def demo_command(
    out: Annotated[Path, typer.Option(help="Folder for the phantom and the run.")] = Path("demo"),
    method: Annotated[str, typer.Option(help=f"Method preset: {', '.join(PRESETS)}.")] = "deform3dgs",
    iters: Annotated[int, typer.Option(help="Training iterations.")] = DEMO_ITERATIONS,
) -> None:
    """Generate the small phantom, train, evaluate against its ground truth, render videos and
    write an HTML report."""
    console = Console()
    scene_dir, run_dir = out / "phantom", out / "run"
    if not (scene_dir / "poses_bounds.npy").is_file():
        console.rule("1/4 phantom")
        generate_phantom(PhantomConfig(preset="small", motion="pulling"), scene_dir)
    print_summary_table(scene_dir)
    console.rule("2/4 train")
    resume = (run_dir / "checkpoints" / "latest.pt").is_file()
    train_run(method_config(method), scene_dir, run_dir, resume=resume, iterations=iters)
    console.rule("3/4 evaluate")
    evaluate_and_report(run_dir)
    console.rule("4/4 render and report")
    videos = write_run_videos(load_trained_run(run_dir), run_dir / "videos", fps=10.0)
    report = write_report([run_dir], run_dir / "report.html")
    console.print(f"\nresults in {run_dir}: metrics.json, "
                  + ", ".join(str(v.relative_to(run_dir)) for v in videos))
    console.print(f"report: {report}")

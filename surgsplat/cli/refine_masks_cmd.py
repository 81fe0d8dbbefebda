"""`surgsplat refine-masks RUN --out SCENE`: the run's scene with its tool masks refined by the
run's tissue model, to train again on."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.cli.progress import progress_bar
from surgsplat.pipeline.refine_masks import RefineConfig, refine_masks
from surgsplat.train.run import load_trained_run, run_lock


def refine_masks_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    out: Annotated[Path, typer.Option(help="New scene folder to write: the run's scene with "
                                           "the refined masks/.")],
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
    tool_z: Annotated[float, typer.Option(
        help="Robust z-score of the tissue render's residual above which a pixel that moves "
             "on its own becomes tool.")] = RefineConfig.tool_z,
    tissue_z: Annotated[float, typer.Option(
        help="Robust z-score below which a masked pixel becomes tissue.")] = RefineConfig.tissue_z,
) -> None:
    """Refine the tool masks with a trained run: what the tissue model persistently fails to
    explain and what moves on its own becomes tool; masked tissue it explains becomes tissue.
    Train again on the new scene."""
    config = RefineConfig(tool_z=tool_z, tissue_z=tissue_z)
    with run_lock(run_dir):
        run = load_trained_run(run_dir, data)
        with progress_bar() as bar:
            task = bar.add_task("refine masks", total=len(run.scene.frames))
            summary = refine_masks(run, out, config,
                                   lambda done, total: bar.update(task, completed=done))
    Console().print(f"{out}: {summary.frames_changed} of {len(run.scene.frames)} frames' masks "
                    f"changed; tool added on {100 * summary.added_share:.2f} % and removed from "
                    f"{100 * summary.removed_share:.2f} % of the field of view's pixels. Train "
                    f"again on it: surgsplat train --data {out} ...", markup=False,
                    highlight=False)

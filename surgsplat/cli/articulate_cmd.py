"""`surgsplat articulate RUN`: estimate the tool's articulation (shaft, two revolute jaws) of a
run with a tool field and write RUN/articulation.json."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.export.articulation import articulate, write_articulation
from surgsplat.train.run import TrainedRun, load_trained_run, run_lock


def articulate_and_write(run: TrainedRun, console: Console) -> dict:
    """Estimate `run`'s articulation, write it, print one summary line; returns it."""
    articulation = articulate(run)
    path = write_articulation(run.run_dir, articulation)
    estimated = sum(record["estimated"] for record in articulation["frames"])
    limits = ", ".join(f"[{low:.1f}, {high:.1f}]" for low, high in articulation["limits_deg"])
    console.print(f"articulation of {articulation['parts']} tool Gaussians (shaft, jaws), "
                  f"{estimated} frames estimated, jaw ranges {limits} deg: {path}",
                  markup=False, highlight=False)
    return articulation


def articulate_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train` "
                                                 "with a method that has a tool field.")],
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
) -> None:
    """Estimate the tool's shaft and two revolute jaws (axis, per-frame angles) into
    RUN/articulation.json."""
    with run_lock(run_dir):
        articulate_and_write(load_trained_run(run_dir, data), Console())

"""`surgsplat articulate RUN`: estimate the tool's articulation (shaft, two revolute jaws) of a
run with a tool field and write RUN/articulation.json."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.export.articulation import ARTICULATION_FILE
from surgsplat.pipeline.articulate import articulate_run, articulation_summary
from surgsplat.train.run import load_trained_run, run_lock


def articulate_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train` "
                                                 "with a method that has a tool field.")],
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
) -> None:
    """Estimate the tool's shaft and two revolute jaws (axis, per-frame angles) into
    RUN/articulation.json."""
    with run_lock(run_dir):
        articulation = articulate_run(load_trained_run(run_dir, data))
    Console().print(articulation_summary(articulation, run_dir / ARTICULATION_FILE),
                    markup=False, highlight=False)

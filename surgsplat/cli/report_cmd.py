"""`surgsplat report RUN [RUN ...] --out report.html`: one self-contained HTML report."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.errors import DataError, SurgsplatError
from surgsplat.export.report import write_report


def report_command(
    runs: Annotated[list[Path], typer.Argument(help="Run folders written by `surgsplat train`.")],
    out: Annotated[Path, typer.Option(
        help="HTML file to write (a new file, or a report surgsplat wrote).")]
        = Path("report.html"),
    frames: Annotated[int, typer.Option(
        help="Test frames shown per run, 0 or more (0: none; more than a run has: all of "
             "them).")] = 4,
) -> None:
    """Metrics with their conventions, training curves and test frames (truth, render, error,
    depth, normals) of one or more runs, in one HTML file that opens offline."""
    if frames < 0:
        raise SurgsplatError(f"--frames must be 0 or more (test frames shown per run), got "
                             f"{frames}")
    try:
        path = write_report(runs, out, max_frames=frames)
    except DataError as err:
        if err.path != out:
            raise
        raise SurgsplatError(f"--out {out}: {err.problem}") from None
    except OSError as err:
        if err.filename != str(out):
            raise
        raise SurgsplatError(f"--out {out}: {err.strerror or err}") from None
    Console().print(f"report: {path}")

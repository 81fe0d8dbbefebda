"""`surgsplat report RUN [RUN ...] --out report.html`: one self-contained HTML report."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.export.report import write_report


def report_command(
    runs: Annotated[list[Path], typer.Argument(help="Run folders written by `surgsplat train`.")],
    out: Annotated[Path, typer.Option(help="HTML file to write.")] = Path("report.html"),
    frames: Annotated[int, typer.Option(help="Test frames shown per run.")] = 4,
) -> None:
    """Metrics with their conventions, training curves and test frames (truth, render, error,
    depth, normals) of one or more runs, in one HTML file that opens offline."""
    path = write_report(runs, out, max_frames=max(frames, 0))
    Console().print(f"report: {path}")
